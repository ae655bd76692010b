! A mock Fortran simulation that uses gsenc the way a production code would:
! the same moving, deforming blobs as examples_c/mock_field.h, on a 64^3 grid
! of doubles with one ghost layer on every side. At every output step the
! interior section u(1:n, 1:n, 1:n) is pushed as it lies in memory (the
! module passes its strides; the ghosts hold garbage and must be skipped),
! encoded (warm-started from the previous step) and written by gsenc as
! OUTPUT_DIR/fortran_grid_STEP.gsm. At the end the last model is read back
! and evaluated at the blob centres.
!
! usage: mock_solver_f OUTPUT_DIR [STEPS [BUDGET [ITERATIONS [WARM_ITERATIONS]]]]
program mock_solver_f
    use, intrinsic :: iso_c_binding, only: c_ptr, c_null_ptr, c_int, c_double
    use, intrinsic :: iso_fortran_env, only: int64, real32, real64, error_unit
    use gsenc
    implicit none
    integer, parameter :: n = 64, blobs = 4
    real(real64), parameter :: dt = 0.05d0
    real(real64), allocatable :: u(:, :, :)
    type(gsenc_config) :: cfg
    type(gsenc_model_info) :: info
    type(c_ptr) :: enc = c_null_ptr, model = c_null_ptr
    character(len=4096) :: outdir, arg
    integer :: steps, step, i, j, k, b
    integer(int64) :: last
    real(c_double) :: psnr, t, x(3), centres(3, blobs), width(3), amplitude
    real(real32) :: at(blobs)

    if (command_argument_count() < 1) then
        write (error_unit, '(a)') 'usage: mock_solver_f OUTPUT_DIR [STEPS [BUDGET [ITERATIONS [WARM_ITERATIONS]]]]'
        stop 2
    end if
    call get_command_argument(1, outdir)
    steps = int_arg(2, 20)
    cfg = gsenc_config_default()
    cfg%budget = int_arg(3, 3000)
    cfg%iterations = int_arg(4, 0)
    cfg%warm_iterations = int_arg(5, 0)
    cfg%warm_start = GSENC_WARM_AUTO
    cfg%fixed_range = 1
    cfg%value_min = 0
    cfg%value_max = 4
    cfg%threads = 0 ! this mock waits for every step, so the encode may use every core
    call check(gsenc_encoder_create(cfg, enc, output_dir=trim(outdir)), 'gsenc_encoder_create')

    allocate (u(0:n + 1, 0:n + 1, 0:n + 1))
    do step = 0, steps - 1
        t = step * dt * 4
        u = 1d30 ! ghost garbage
        do k = 1, n
            do j = 1, n
                do i = 1, n
                    x = [(i - 0.5d0) / n, (j - 0.5d0) / n, (k - 0.5d0) / n]
                    u(i, j, k) = field(x, t)
                end do
            end do
        end do
        call check(gsenc_push_grid(enc, 'fortran_grid', int(step, int64), u(1:n, 1:n, 1:n), &
            origin=[0d0, 0d0, 0d0], spacing=1d0 / n, time=t), 'gsenc_push_grid')
        call check(gsenc_wait(enc), 'gsenc_wait')
        call check(gsenc_encoder_last_step(enc, 'fortran_grid', last, psnr), 'gsenc_encoder_last_step')
        write (*, '(a, i3, a, f6.2, a)') 'step ', last, '  fortran_grid ', psnr, ' dB'
    end do
    call gsenc_encoder_destroy(enc)

    ! Read the last model back and evaluate it where the blobs are.
    write (arg, '(a, a, i6.6, a)') trim(outdir), '/fortran_grid_', steps - 1, '.gsm'
    call check(gsenc_model_read(trim(arg), model), 'gsenc_model_read')
    call check(gsenc_model_info_get(model, info), 'gsenc_model_info_get')
    t = (steps - 1) * dt * 4
    do b = 1, blobs
        call blob(b - 1, t, centres(:, b), width, amplitude)
    end do
    call check(gsenc_model_evaluate(model, centres, at), 'gsenc_model_evaluate')
    do b = 1, blobs
        write (*, '(a, i1, a, f7.4, a, f7.4)') 'blob ', b, ': model ', at(b), '  field ', field(centres(:, b), t)
    end do
    call gsenc_model_destroy(model)

contains

    integer function int_arg(index, default)
        integer, intent(in) :: index, default
        character(len=64) :: s
        int_arg = default
        if (command_argument_count() >= index) then
            call get_command_argument(index, s)
            read (s, *) int_arg
        end if
    end function

    subroutine check(status, what)
        integer(c_int), intent(in) :: status
        character(len=*), intent(in) :: what
        if (status /= GSENC_STATUS_OK) then
            write (error_unit, '(a, a, i0, a, a)') what, ' failed (', status, '): ', gsenc_last_error_message()
            error stop 1
        end if
    end subroutine

    ! examples_c/mock_field.h, term for term.
    subroutine blob(b, t, centre, width, amplitude)
        integer, intent(in) :: b
        real(real64), intent(in) :: t
        real(real64), intent(out) :: centre(3), width(3), amplitude
        real(real64) :: phase, w
        phase = 1.7d0 * b
        w = 1d0 + 0.35d0 * b
        centre = [0.5d0 + 0.22d0 * cos(w * t + phase), 0.5d0 + 0.22d0 * sin(w * t + phase), &
            0.5d0 + 0.15d0 * sin(0.5d0 * w * t + 2d0 * phase)]
        width = [0.06d0 + 0.02d0 * b + 0.02d0 * sin(2d0 * t + phase), &
            0.06d0 + 0.01d0 * b + 0.02d0 * cos(1.5d0 * t + phase), 0.05d0 + 0.015d0 * b]
        amplitude = 1d0 + 0.5d0 * b
    end subroutine

    real(real64) function field(x, t)
        real(real64), intent(in) :: x(3), t
        real(real64) :: c(3), s(3), a
        integer :: b
        field = 0
        do b = 0, blobs - 1
            call blob(b, t, c, s, a)
            field = field + a * exp(-0.5d0 * sum(((x - c) / s)**2))
        end do
    end function
end program mock_solver_f
