! The Fortran module `gsenc` from gfortran: every wrapper on its good path
! (array sections passed through strides, both real kinds, the three input
! forms, decode and evaluate agreeing) and its error paths (NULL and
! destroyed handles, mismatched or misshapen arrays, NaN, a non-contiguous
! output, an unwritable folder), each with its status and message; and a
! restart that resumes a series from its stored model.
! usage: module_test SCRATCH_DIR   (exit status 0 when every check passes)
program module_test
    use, intrinsic :: iso_c_binding
    use, intrinsic :: iso_fortran_env, only: int64, real32, real64
    use, intrinsic :: ieee_arithmetic, only: ieee_value, ieee_quiet_nan
    use gsenc
    implicit none
    integer, parameter :: n = 16
    type(gsenc_config) :: cfg
    type(gsenc_model_info) :: info
    type(gsenc_job) :: job
    type(c_ptr) :: enc = c_null_ptr, copy, model = c_null_ptr
    character(len=1024) :: dir
    integer :: passed = 0, failed = 0, i, j, k, p
    real(real32), allocatable :: wide(:, :, :), decoded(:, :, :), big(:, :, :), values4(:), again(:, :, :)
    real(real64), allocatable :: records(:, :), h(:), centres(:, :), edges(:, :), pts(:, :)
    real(real32), allocatable :: hex_points(:, :), hex_values(:), at(:)
    integer(c_int64_t), allocatable :: conn(:, :)
    integer(int64) :: last
    real(c_double) :: psnr, x(3), se
    integer :: np

    call get_command_argument(1, dir)
    call expect(int(gsenc_version()), 100 * 0 + 1 * 100 + 0, 'gsenc_version is 0.1.0')
    cfg = gsenc_config_default()
    call expect(int(cfg%budget), 32000, 'default budget')
    call expect(int(c_sizeof(cfg)), 256, 'gsenc_config is the size C sees')
    call expect(int(cfg%preview_width), 512, 'default preview width')
    call expect(int(cfg%support), GSENC_SUPPORT_STORED, 'default support')
    call expect(int(cfg%encoder_priority), GSENC_PRIORITY_NORMAL, 'default encoder priority')
    cfg%budget = 100
    cfg%iterations = 60
    cfg%warm_iterations = 30
    cfg%dims = [n, n, n]
    cfg%has_bounds = 1
    cfg%bounds_min = 0
    cfg%bounds_max = 1
    call expect(gsenc_encoder_create(cfg, enc, output_dir=trim(dir)), GSENC_STATUS_OK, 'create')
    call expect(gsenc_encoder_reserve(enc, int(n, int64)**3), GSENC_STATUS_OK, 'reserve the grid push')
    call expect(gsenc_encoder_reserve(c_null_ptr, 8_int64), GSENC_STATUS_NULL_POINTER, 'reserve on a NULL encoder')

    ! A real32 grid pushed as every other cell of a wider array: strides (2, 2n, 4n^2).
    allocate (wide(2 * n, n, n))
    wide = -1e30
    do k = 1, n
        do j = 1, n
            do i = 1, n
                wide(2 * i - 1, j, k) = real(blob([(i - 0.5d0) / n, (j - 0.5d0) / n, (k - 0.5d0) / n]), real32)
            end do
        end do
    end do
    call expect(gsenc_push_grid(enc, 'grid', 0_int64, wide(1:2 * n:2, :, :), [0d0, 0d0, 0d0], 1d0 / n), &
        GSENC_STATUS_OK, 'push a strided real32 section')
    ! real64 particles as rows 1:3 (positions) and 4 (values) of a (4, n) record array.
    np = 4000
    allocate (records(4, np), h(np))
    do p = 1, np
        x = [mod(p * 0.6180339887d0, 1d0), mod(p * 0.7548776662d0, 1d0), mod(p * 0.5698402910d0, 1d0)]
        records(1:3, p) = x
        records(4, p) = blob(x)
    end do
    h = 0.09d0
    call expect(gsenc_push_particles(enc, 'tracers', 0_int64, records(1:3, :), h, records(4, :), time=0.5d0), &
        GSENC_STATUS_OK, 'push particles from a record array')
    ! real64 AMR boxes: 8^3 cells.
    allocate (centres(3, 512), edges(3, 512))
    p = 0
    do k = 1, 8
        do j = 1, 8
            do i = 1, 8
                p = p + 1
                centres(:, p) = [(i - 0.5d0) / 8, (j - 0.5d0) / 8, (k - 0.5d0) / 8]
            end do
        end do
    end do
    edges = 1d0 / 8
    call expect(gsenc_push_cells_boxes(enc, 'amr', 0_int64, centres, edges, [(blob(centres(:, p)), p = 1, 512)]), &
        GSENC_STATUS_OK, 'push AMR boxes')
    ! real32 hexahedra: one cube split in 2^3 hexahedra on a 3^3 point lattice.
    allocate (hex_points(3, 27), conn(8, 8), hex_values(8))
    do k = 0, 2
        do j = 0, 2
            do i = 0, 2
                hex_points(:, 1 + i + 3 * j + 9 * k) = [i * 0.5, j * 0.5, k * 0.5]
            end do
        end do
    end do
    p = 0
    do k = 0, 1
        do j = 0, 1
            do i = 0, 1
                p = p + 1
                conn(:, p) = [node(i, j, k), node(i + 1, j, k), node(i + 1, j + 1, k), node(i, j + 1, k), &
                    node(i, j, k + 1), node(i + 1, j, k + 1), node(i + 1, j + 1, k + 1), node(i, j + 1, k + 1)]
                hex_values(p) = real(p, real32)
            end do
        end do
    end do
    call expect(gsenc_push_cells_hexahedra(enc, 'hex', 0_int64, hex_points, conn, hex_values), GSENC_STATUS_OK, &
        'push hexahedra')
    call expect(gsenc_wait(enc), GSENC_STATUS_OK, 'wait for step 0')
    call expect(gsenc_encoder_last_step(enc, 'grid', last, psnr), GSENC_STATUS_OK, 'last step')
    call check(last == 0 .and. psnr > 25, 'the strided grid encodes its own cells (PSNR above 25 dB)')
    call expect(gsenc_encoder_last_step(enc, 'tracers', last, psnr), GSENC_STATUS_OK, 'last step of particles')
    call check(psnr > 20, 'the particles encode')
    ! A section reversed along x and y: negative memory strides, taken as they are.
    call expect(gsenc_push_grid(enc, 'grid_reversed', 0_int64, wide(2 * n - 1:1:-2, n:1:-1, :), [0d0, 0d0, 0d0], 1d0 / n), &
        GSENC_STATUS_OK, 'push a reversed real32 section')
    call expect(gsenc_wait(enc, 'grid_reversed'), GSENC_STATUS_OK, 'wait for the reversed section')
    call expect(gsenc_encoder_last_step(enc, 'grid_reversed', last, psnr), GSENC_STATUS_OK, 'last step of the reversed section')
    call check(last == 0 .and. psnr > 25, 'the reversed section encodes its own cells')

    ! Error paths, each with its status and a message.
    call expect(gsenc_push_particles(enc, 'tracers', 1_int64, records(1:3, :), h(1:10), records(4, :)), &
        GSENC_STATUS_INVALID_ARGUMENT, 'smoothing lengths shorter than the values')
    call check(index(gsenc_last_error_message(), 'differ in length') > 0, 'message: '//gsenc_last_error_message())
    call expect(gsenc_push_particles(enc, 'tracers', 1_int64, records(1:2, :), h, records(4, :)), &
        GSENC_STATUS_INVALID_ARGUMENT, 'positions not (3, n)')
    call expect(gsenc_push_cells_boxes(enc, 'amr', 1_int64, centres, edges(:, 1:5), [(1d0, p = 1, 512)]), &
        GSENC_STATUS_INVALID_ARGUMENT, 'edges shorter than centres')
    records(4, 7) = ieee_value(1d0, ieee_quiet_nan)
    call expect(gsenc_push_particles(enc, 'tracers', 1_int64, records(1:3, :), h, records(4, :)), &
        GSENC_STATUS_INVALID_DATA, 'a NaN value')
    call check(len(gsenc_last_error_message()) > 0, 'NaN has a message')
    call expect(gsenc_push_grid(c_null_ptr, 'grid', 1_int64, wide, [0d0, 0d0, 0d0], 1d0), &
        GSENC_STATUS_NULL_POINTER, 'a NULL encoder')
    call expect(gsenc_encoder_write_model(enc, 'nothing', trim(dir)//'/x.gsm'), GSENC_STATUS_CALL_ORDER, &
        'write a field never encoded')
    call expect(gsenc_encoder_write_model(enc, 'grid', '/nonexistent-dir/x.gsm'), GSENC_STATUS_IO, &
        'write into a missing folder')
    ! A warm-started second step of the grid.
    call expect(gsenc_push_grid(enc, 'grid', 1_int64, wide(1:2 * n:2, :, :), [0d0, 0d0, 0d0], 1d0 / n), &
        GSENC_STATUS_OK, 'push step 1')
    call expect(gsenc_wait(enc, 'grid'), GSENC_STATUS_OK, 'wait for step 1 of the grid')
    call expect(gsenc_poll(enc, 'grid', 1_int64, job), GSENC_STATUS_OK, 'poll step 1')
    call expect(gsenc_encoder_last_step(enc, 'grid', last, psnr), GSENC_STATUS_OK, 'last step 1')
    call check(job%state == GSENC_JOB_DONE .and. abs(job%psnr - psnr) < 1d-12 .and. last == 1, 'poll: done, its PSNR')
    call expect(gsenc_poll(enc, 'grid', 9_int64, job), GSENC_STATUS_CALL_ORDER, 'poll a step never pushed')
    copy = enc
    call gsenc_encoder_destroy(enc)
    call check(.not. c_associated(enc), 'destroy nulls the handle')
    call expect(gsenc_wait(copy), GSENC_STATUS_INVALID_ARGUMENT, 'wait after destroy')
    call gsenc_encoder_destroy(copy)

    ! Read the warm-started step back: decode and evaluate agree; info is right.
    call expect(gsenc_model_read(trim(dir)//'/grid_000001.gsm', model), GSENC_STATUS_OK, 'read')
    call expect(gsenc_model_info_get(model, info), GSENC_STATUS_OK, 'info')
    call check(info%step == 1 .and. info%warm_started == 1 .and. info%iterations == 30 .and. info%count == 100, &
        'info: step 1, warm-started for 30 iterations, 100 Gaussians')
    allocate (decoded(n, n, n), at(3))
    call expect(gsenc_model_decode(model, decoded), GSENC_STATUS_OK, 'decode')
    se = 0
    do k = 1, n
        do j = 1, n
            do i = 1, n
                se = se + (decoded(i, j, k) - wide(2 * i - 1, j, k))**2
            end do
        end do
    end do
    call check(10 * log10(maxval(wide(1:2 * n:2, :, :))**2 / (se / n**3)) > 25, 'decode matches the pushed field')
    allocate (pts(3, 3))
    pts(:, 1) = [0.5d0, 0.5d0, 0.5d0] / n
    pts(:, 2) = [8.5d0, 7.5d0, 8.5d0] / n
    pts(:, 3) = [15.5d0, 3.5d0, 0.5d0] / n
    call expect(gsenc_model_evaluate(model, pts, at), GSENC_STATUS_OK, 'evaluate')
    call check(abs(at(1) - decoded(1, 1, 1)) < 1e-4 .and. abs(at(2) - decoded(9, 8, 9)) < 1e-4 &
        .and. abs(at(3) - decoded(16, 4, 1)) < 1e-4, 'evaluate at cell centres equals decode')
    allocate (big(2 * n, n, n), values4(2))
    call expect(gsenc_model_decode(model, big(1:2 * n:2, :, :)), GSENC_STATUS_INVALID_ARGUMENT, &
        'decode into a non-contiguous section')
    call check(index(gsenc_last_error_message(), 'contiguous') > 0, 'message: '//gsenc_last_error_message())
    call expect(gsenc_model_evaluate(model, pts, values4), GSENC_STATUS_INVALID_ARGUMENT, 'evaluate: out too short')
    call gsenc_model_destroy(model)
    call check(.not. c_associated(model), 'model destroy nulls the handle')
    call expect(gsenc_model_read(trim(dir)//'/missing.gsm', model), GSENC_STATUS_IO, 'read a missing file')

    ! A restart: a new encoder resumes the grid from its step 0 as stored,
    ! and its step 1 is the unbroken run's.
    call expect(gsenc_encoder_create(cfg, enc), GSENC_STATUS_OK, 'create the restarted encoder')
    call expect(gsenc_model_read(trim(dir)//'/grid_000000.gsm', model), GSENC_STATUS_OK, 'read step 0')
    call expect(gsenc_encoder_resume(enc, model), GSENC_STATUS_OK, 'resume from step 0')
    call gsenc_model_destroy(model)
    call expect(gsenc_encoder_resume(enc, c_null_ptr), GSENC_STATUS_NULL_POINTER, 'resume from a NULL model')
    call expect(gsenc_push_grid(enc, 'grid', 0_int64, wide(1:2 * n:2, :, :), [0d0, 0d0, 0d0], 1d0 / n), &
        GSENC_STATUS_INVALID_ARGUMENT, 'push the resumed step again')
    call expect(gsenc_push_grid(enc, 'grid', 1_int64, wide(1:2 * n:2, :, :), [0d0, 0d0, 0d0], 1d0 / n), &
        GSENC_STATUS_OK, 'push step 1 after the restart')
    call expect(gsenc_wait(enc), GSENC_STATUS_OK, 'wait after the restart')
    call expect(gsenc_encoder_write_model(enc, 'grid', trim(dir)//'/restarted.gsm'), GSENC_STATUS_OK, &
        'write the restarted step 1')
    call gsenc_encoder_destroy(enc)
    allocate (again(n, n, n))
    call expect(gsenc_model_read(trim(dir)//'/restarted.gsm', model), GSENC_STATUS_OK, 'read the restarted step 1')
    call expect(gsenc_model_decode(model, again), GSENC_STATUS_OK, 'decode the restarted step 1')
    call gsenc_model_destroy(model)
    call check(all(again == decoded), 'the restarted step 1 decodes as the unbroken run''s')
    ! The same restart from the encoder's own folder, which holds step 0.
    call expect(gsenc_encoder_create(cfg, enc, output_dir=trim(dir)), GSENC_STATUS_OK, 'create on the same folder')
    call expect(gsenc_encoder_resume_stored(enc, 'grid', 9_int64), GSENC_STATUS_IO, 'resume from a step not stored')
    call expect(gsenc_encoder_resume_stored(enc, 'grid', 0_int64), GSENC_STATUS_OK, 'resume from the stored step 0')
    call expect(gsenc_push_grid(enc, 'grid', 1_int64, wide(1:2 * n:2, :, :), [0d0, 0d0, 0d0], 1d0 / n), &
        GSENC_STATUS_OK, 'push step 1 after the stored restart')
    call expect(gsenc_wait(enc), GSENC_STATUS_OK, 'wait after the stored restart')
    call gsenc_encoder_destroy(enc)
    call expect(gsenc_model_read(trim(dir)//'/grid_000001.gsm', model), GSENC_STATUS_OK, 'read its step 1')
    call expect(gsenc_model_decode(model, again), GSENC_STATUS_OK, 'decode its step 1')
    call gsenc_model_destroy(model)
    call check(all(again == decoded), 'the step 1 of the stored restart decodes as the unbroken run''s')

    write (*, '(a, i0, a, i0, a)') 'fortran: ', passed, ' passed, ', failed, ' failed'
    if (failed > 0) error stop 1

contains

    real(real64) function blob(x)
        real(real64), intent(in) :: x(3)
        blob = 2 * exp(-sum((x - [0.45d0, 0.5d0, 0.55d0])**2) / 0.02d0)
    end function

    integer(c_int64_t) function node(i, j, k)
        integer, intent(in) :: i, j, k
        node = i + 3 * j + 9 * k
    end function

    subroutine check(ok, what)
        logical, intent(in) :: ok
        character(len=*), intent(in) :: what
        if (ok) then
            passed = passed + 1
        else
            failed = failed + 1
            write (*, '(a, a)') 'FAIL: ', what
        end if
    end subroutine

    subroutine expect(got, want, what)
        integer, intent(in) :: got, want
        character(len=*), intent(in) :: what
        if (got /= want) then
            write (*, '(a, a, a, i0, a, i0, a, a)') 'FAIL: ', what, ': status ', got, ', want ', want, ': ', &
                gsenc_last_error_message()
            failed = failed + 1
        else
            passed = passed + 1
        end if
    end subroutine
end program module_test
