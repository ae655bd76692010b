! The Fortran module over MPI, run under mpirun (tests/mpi.sh): the
! communicator as `integer :: comm`, each rank pushing its slab of a grid
! (a section of an array with ghost layers), the collective misuse error,
! particles, none of them on the last rank at the second step.
program gsenc_mpi_test
    use mpi
    use gsenc
    use iso_c_binding
    implicit none
    integer, parameter :: n = 16
    type(gsenc_config) :: cfg
    type(c_ptr) :: enc
    integer :: ierr, provided, rank, nranks, x0, x1, i, j, k, failures, total, np
    real(c_float), allocatable :: slab(:, :, :)
    real(c_double) :: pos(3, 512), hh(512), val(512)
    character(len=256) :: dir

    failures = 0
    call get_command_argument(1, dir)
    call mpi_init_thread(MPI_THREAD_FUNNELED, provided, ierr)
    call mpi_comm_rank(MPI_COMM_WORLD, rank, ierr)
    call mpi_comm_size(MPI_COMM_WORLD, nranks, ierr)
    x0 = rank * n / nranks
    x1 = (rank + 1) * n / nranks
    ! One ghost layer on every side; the interior is pushed as a section.
    allocate (slab(x0:x1 + 1, 0:n + 1, 0:n + 1))
    slab = -1.0
    do k = 1, n
        do j = 1, n
            do i = x0 + 1, x1
                slab(i, j, k) = exp(-((i - 8.5)**2 + (j - 8.5)**2 + (k - 8.5)**2) / 20.0)
            end do
        end do
    end do

    cfg = gsenc_config_default()
    cfg%budget = 80
    cfg%iterations = 40
    cfg%halo = 3
    call expect(gsenc_encoder_create_mpi(cfg, MPI_COMM_WORLD, enc, trim(dir)), GSENC_STATUS_OK, "create_mpi")
    call expect(gsenc_push_grid(enc, "rho", 1_c_int64_t, slab(x0 + 1:x1, 1:n, 1:n), &
        [dble(x0) / n, 0d0, 0d0], 1d0 / n), GSENC_STATUS_OK, "push of a section")
    if (nranks > 1) then
        call expect(gsenc_push_grid(enc, "rho", int(2 + rank, c_int64_t), slab(x0 + 1:x1, 1:n, 1:n), &
            [dble(x0) / n, 0d0, 0d0], 1d0 / n), GSENC_STATUS_MPI, "ranks pushing different steps")
    end if
    ! Particles on a lattice, each rank those in its x share; at step 2
    ! the last rank holds none: zero-size arrays, taken at a later step.
    np = 0
    do k = 1, 8
        do j = 1, 8
            do i = 1, 8
                if ((i - 0.5d0) / 8 * nranks < rank .or. (i - 0.5d0) / 8 * nranks >= rank + 1) cycle
                np = np + 1
                pos(:, np) = [(i - 0.5d0) / 8, (j - 0.5d0) / 8, (k - 0.5d0) / 8]
                hh(np) = 0.2d0
                val(np) = exp(-sum((pos(:, np) - 0.5d0)**2) / 0.05d0)
            end do
        end do
    end do
    call expect(gsenc_push_particles(enc, "tracer", 1_c_int64_t, pos(:, 1:np), hh(1:np), val(1:np)), GSENC_STATUS_OK, &
        "push of particles")
    ! (One rank alone holding none would have nothing to encode.)
    if (rank == nranks - 1 .and. nranks > 1) np = 0
    call expect(gsenc_push_particles(enc, "tracer", 2_c_int64_t, pos(:, 1:np), hh(1:np), val(1:np)), GSENC_STATUS_OK, &
        "push of no particles on the last rank at a later step")
    call expect(gsenc_wait(enc), GSENC_STATUS_OK, "wait")
    call gsenc_encoder_destroy(enc)

    call mpi_allreduce(failures, total, 1, MPI_INTEGER, MPI_SUM, MPI_COMM_WORLD, ierr)
    if (rank == 0) print '(a, i0, a, i0, a)', 'fortran-mpi (', nranks, ' ranks): ', total, ' failed'
    call mpi_finalize(ierr)
    if (total /= 0) error stop 1
contains
    subroutine expect(got, want, what)
        integer(c_int), intent(in) :: got, want
        character(len=*), intent(in) :: what
        if (got /= want) then
            failures = failures + 1
            print '(a, i0, a, a, a, i0, a, i0, a, a)', 'rank ', rank, ' FAIL ', what, ': got ', got, ' want ', want, ': ', &
                gsenc_last_error_message()
        end if
    end subroutine
end program
