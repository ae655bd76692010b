! gsenc: in-situ encoding of 3D scalar fields into fixed budgets of Gaussians.
!
! The Fortran module over the C API of gsenc.h (Fortran 2008, iso_c_binding).
! Two layers:
!  - the C functions themselves, bound under their C names with a `_c` suffix
!    (gsenc_push_grid_c, ...), taking the bind(c) structs and type(c_ptr);
!  - Fortran-friendly procedures under the C names (gsenc_push_grid, ...):
!    character strings instead of NUL-terminated arrays, assumed-shape arrays
!    of real32 or real64 whose memory strides are passed on (so array sections
!    that skip ghost layers go through without a copy), optional arguments.
! Every function returns an integer(c_int) status, GSENC_STATUS_OK (0) on
! success; gsenc_last_error_message() gives the calling thread's message.
! Handles (encoder, model) are type(c_ptr): initialise them to c_null_ptr,
! free them with gsenc_encoder_destroy / gsenc_model_destroy.
!
! Threading and ownership are as in gsenc.h: calls on one encoder from
! several threads (an OpenMP loop over fields) run one at a time; a model is
! read by any number at once; a destroy waits for the calls in flight on its
! handle; pushed arrays are copied before the call returns. Connectivity of hexahedra is 0-based, in VTK order, as in C.
!
! This source is installed beside gsenc.mod, so that a build with another
! Fortran compiler can compile it itself (see the CMake package).
module gsenc
    use, intrinsic :: iso_c_binding
    use, intrinsic :: iso_fortran_env, only: real32, real64, int64
    use, intrinsic :: ieee_arithmetic, only: ieee_value, ieee_quiet_nan
    implicit none
    private

    ! Status codes (gsenc_status): fixed values, only ever appended to.
    integer(c_int), parameter, public :: GSENC_STATUS_OK = 0, GSENC_STATUS_NULL_POINTER = 1, &
        GSENC_STATUS_INVALID_ARGUMENT = 2, GSENC_STATUS_INVALID_DATA = 3, GSENC_STATUS_FORMAT = 4, &
        GSENC_STATUS_VERSION = 5, GSENC_STATUS_IO = 6, GSENC_STATUS_CALL_ORDER = 7, &
        GSENC_STATUS_STRUCT_SIZE = 8, GSENC_STATUS_INTERNAL = 9, GSENC_STATUS_BUSY = 10, &
        GSENC_STATUS_SKIPPED = 11, GSENC_STATUS_CANCELLED = 12, GSENC_STATUS_MPI = 13, &
        GSENC_STATUS_DEVICE = 14
    integer(c_int32_t), parameter, public :: GSENC_DTYPE_FLOAT32 = 0, GSENC_DTYPE_FLOAT64 = 1
    integer(c_int32_t), parameter, public :: GSENC_SCHEDULE_FULL = 0, GSENC_SCHEDULE_MATCHED = 1, &
        GSENC_SCHEDULE_SHORT = 2, GSENC_SCHEDULE_TUNED = 3, GSENC_SCHEDULE_TUNED_FULL = 4
    integer(c_int32_t), parameter, public :: GSENC_WARM_OFF = 0, GSENC_WARM_COARSE = 1, GSENC_WARM_DENSE = 2, &
        GSENC_WARM_AUTO = 3
    integer(c_int32_t), parameter, public :: GSENC_WARM_TAKEN_NONE = 0, GSENC_WARM_TAKEN_KEPT = 1, &
        GSENC_WARM_TAKEN_REPAIRED = 2, GSENC_WARM_TAKEN_FRESH = 3
    integer(c_int32_t), parameter, public :: GSENC_TRANSFORM_LINEAR = 0, GSENC_TRANSFORM_LOG10 = 1
    integer(c_int32_t), parameter, public :: GSENC_PAYLOAD_F32 = 0, GSENC_PAYLOAD_8BIT = 1, &
        GSENC_PAYLOAD_8BIT_U16 = 2, GSENC_PAYLOAD_PACKED = 3
    integer(c_int32_t), parameter, public :: GSENC_CELLS_BOXES = 0, GSENC_CELLS_HEXAHEDRA = 1
    integer(c_int32_t), parameter, public :: GSENC_QUEUE_BLOCK = 0, GSENC_QUEUE_SKIP = 1, GSENC_QUEUE_BUSY = 2
    integer(c_int32_t), parameter, public :: GSENC_OUTPUT_FOLDER = 0, GSENC_OUTPUT_HDF5 = 1
    integer(c_int32_t), parameter, public :: GSENC_SUPPORT_STORED = 0, GSENC_SUPPORT_NONE = 1
    integer(c_int32_t), parameter, public :: GSENC_BACKEND_AUTO = 0, GSENC_BACKEND_CPU = 1, GSENC_BACKEND_GPU = 2
    integer(c_int32_t), parameter, public :: GSENC_PREVIEW_NONE = 0, GSENC_PREVIEW_SLICE = 1, GSENC_PREVIEW_VOLUME = 2
    integer(c_int32_t), parameter, public :: GSENC_PRIORITY_NORMAL = 0, GSENC_PRIORITY_LOW = 1, GSENC_PRIORITY_IDLE = 2
    integer(c_int32_t), parameter, public :: GSENC_JOB_QUEUED = 0, GSENC_JOB_RUNNING = 1, GSENC_JOB_DONE = 2, &
        GSENC_JOB_FAILED = 3, GSENC_JOB_SKIPPED = 4, GSENC_JOB_CANCELLED = 5

    ! gsenc_config. Unsigned C fields are signed here; values stay small.
    ! Get one with gsenc_config_default(); output_dir is given to
    ! gsenc_encoder_create as a string, not set here.
    type, bind(c), public :: gsenc_config
        integer(c_size_t) :: struct_size = 0
        integer(c_int64_t) :: budget = 0
        integer(c_int32_t) :: schedule = 0, warm_start = 0
        integer(c_int32_t) :: iterations = 0, points = 0
        integer(c_int32_t) :: transform = 0, fixed_range = 0
        real(c_double) :: value_min = 0, value_max = 0
        integer(c_int32_t) :: dims(3) = 0
        integer(c_int32_t) :: has_bounds = 0
        real(c_double) :: bounds_min(3) = 0, bounds_max(3) = 0
        integer(c_int32_t) :: payload = 0, threads = 0
        integer(c_int64_t) :: seed_init = 0, seed_sample = 0
        integer(c_int32_t) :: rank = 0
        integer(c_int32_t) :: support = 0
        type(c_ptr) :: output_dir = c_null_ptr
        integer(c_int32_t) :: warm_iterations = 0
        integer(c_int32_t) :: when_full = 0
        integer(c_int64_t) :: queue_bytes = 0
        integer(c_int32_t) :: output_format = 0
        integer(c_int32_t) :: halo = 0
        integer(c_int32_t) :: backend = 0
        integer(c_int32_t) :: gpu_index = 0
        integer(c_int32_t) :: preview = 0, preview_axis = 0
        real(c_double) :: preview_at = 0, preview_azimuth = 0, preview_elevation = 0
        integer(c_int32_t) :: preview_width = 0, preview_height = 0
        real(c_double) :: target_psnr = 0
        ! The encoder's CPUs as a C string (c_loc of a character array ending
        ! in c_null_char), or GSENC_ENCODER_CPUS in the environment.
        type(c_ptr) :: encoder_cpus = c_null_ptr
        integer(c_int32_t) :: encoder_priority = 0
    end type

    ! gsenc_job: where one pushed step is (gsenc_poll).
    type, bind(c), public :: gsenc_job
        integer(c_size_t) :: struct_size = 0
        integer(c_int32_t) :: state = 0, iteration = 0, iterations = 0, error = 0
        real(c_double) :: psnr = 0
    end type

    type, bind(c), public :: gsenc_grid
        integer(c_size_t) :: struct_size = 0
        integer(c_int32_t) :: dtype = 0
        type(c_ptr) :: data = c_null_ptr
        integer(c_int64_t) :: extents(3) = 0, strides(3) = 0
        real(c_double) :: origin(3) = 0, spacing = 0
    end type

    type, bind(c), public :: gsenc_particles
        integer(c_size_t) :: struct_size = 0
        integer(c_int32_t) :: dtype = 0
        integer(c_int64_t) :: count = 0
        type(c_ptr) :: positions = c_null_ptr
        integer(c_int64_t) :: position_stride = 0, position_component_stride = 0
        type(c_ptr) :: smoothing_length = c_null_ptr
        integer(c_int64_t) :: smoothing_length_stride = 0
        type(c_ptr) :: mass = c_null_ptr
        integer(c_int64_t) :: mass_stride = 0
        type(c_ptr) :: values = c_null_ptr
        integer(c_int64_t) :: value_stride = 0
    end type

    type, bind(c), public :: gsenc_cells
        integer(c_size_t) :: struct_size = 0
        integer(c_int32_t) :: dtype = 0, layout = 0
        integer(c_int64_t) :: count = 0
        type(c_ptr) :: centres = c_null_ptr
        integer(c_int64_t) :: centre_stride = 0, centre_component_stride = 0
        type(c_ptr) :: edges = c_null_ptr
        integer(c_int64_t) :: edge_stride = 0, edge_component_stride = 0
        type(c_ptr) :: points = c_null_ptr
        integer(c_int64_t) :: point_count = 0, point_stride = 0, point_component_stride = 0
        type(c_ptr) :: connectivity = c_null_ptr
        type(c_ptr) :: values = c_null_ptr
        integer(c_int64_t) :: value_stride = 0
    end type

    type, bind(c), public :: gsenc_model_info
        integer(c_size_t) :: struct_size = 0
        integer(c_int64_t) :: count = 0
        integer(c_int64_t) :: dims(3) = 0
        real(c_double) :: origin(3) = 0, spacing = 0
        integer(c_int64_t) :: step = 0
        real(c_double) :: time = 0
        integer(c_int32_t) :: rank = 0, iterations = 0
        integer(c_int32_t) :: warm_started = 0
        real(c_double) :: encode_psnr = 0
        integer(c_int32_t) :: fell_back = 0, warm_taken = 0, warm_moved = 0
    end type

    ! The C functions, under their C names with a `_c` suffix.
    interface
        integer(c_int32_t) function gsenc_version() bind(c, name="gsenc_version")
            import :: c_int32_t
        end function
        integer(c_int) function gsenc_config_init_c(config) bind(c, name="gsenc_config_init")
            import :: c_int, gsenc_config
            type(gsenc_config), intent(inout) :: config
        end function
        integer(c_int) function gsenc_encoder_create_c(config, out) bind(c, name="gsenc_encoder_create")
            import :: c_int, c_ptr, gsenc_config
            type(gsenc_config), intent(in) :: config
            type(c_ptr), intent(out) :: out
        end function
        integer(c_int) function gsenc_encoder_create_mpi_c(config, comm, out) bind(c, name="gsenc_encoder_create_mpi")
            import :: c_int, c_int32_t, c_ptr, gsenc_config
            type(gsenc_config), intent(in) :: config
            integer(c_int32_t), value :: comm
            type(c_ptr), intent(out) :: out
        end function
        subroutine gsenc_encoder_destroy_c(encoder) bind(c, name="gsenc_encoder_destroy")
            import :: c_ptr
            type(c_ptr), value :: encoder
        end subroutine
        integer(c_int) function gsenc_push_grid_c(encoder, field, step, time, grid) bind(c, name="gsenc_push_grid")
            import :: c_int, c_ptr, c_char, c_int64_t, c_double, gsenc_grid
            type(c_ptr), value :: encoder
            character(kind=c_char), intent(in) :: field(*)
            integer(c_int64_t), value :: step
            real(c_double), value :: time
            type(gsenc_grid), intent(in) :: grid
        end function
        integer(c_int) function gsenc_push_particles_c(encoder, field, step, time, particles) &
                bind(c, name="gsenc_push_particles")
            import :: c_int, c_ptr, c_char, c_int64_t, c_double, gsenc_particles
            type(c_ptr), value :: encoder
            character(kind=c_char), intent(in) :: field(*)
            integer(c_int64_t), value :: step
            real(c_double), value :: time
            type(gsenc_particles), intent(in) :: particles
        end function
        integer(c_int) function gsenc_push_cells_c(encoder, field, step, time, cells) bind(c, name="gsenc_push_cells")
            import :: c_int, c_ptr, c_char, c_int64_t, c_double, gsenc_cells
            type(c_ptr), value :: encoder
            character(kind=c_char), intent(in) :: field(*)
            integer(c_int64_t), value :: step
            real(c_double), value :: time
            type(gsenc_cells), intent(in) :: cells
        end function
        integer(c_int) function gsenc_wait_c(encoder, field) bind(c, name="gsenc_wait")
            import :: c_int, c_ptr
            type(c_ptr), value :: encoder, field
        end function
        integer(c_int) function gsenc_poll_c(encoder, field, step, job) bind(c, name="gsenc_poll")
            import :: c_int, c_ptr, c_char, c_int64_t, gsenc_job
            type(c_ptr), value :: encoder
            character(kind=c_char), intent(in) :: field(*)
            integer(c_int64_t), value :: step
            type(gsenc_job), intent(inout) :: job
        end function
        integer(c_int) function gsenc_encoder_cancel(encoder) bind(c, name="gsenc_encoder_cancel")
            import :: c_int, c_ptr
            type(c_ptr), value :: encoder
        end function
        !> Readies the encoder for grid pushes of up to `values` values: the
        !> first push then copies into a buffer whose memory is touched now.
        integer(c_int) function gsenc_encoder_reserve(encoder, values) bind(c, name="gsenc_encoder_reserve")
            import :: c_int, c_ptr, c_int64_t
            type(c_ptr), value :: encoder
            integer(c_int64_t), value :: values
        end function
        !> Continues `model`'s field from it after a restart (before the
        !> field's first push; collective on an MPI encoder).
        integer(c_int) function gsenc_encoder_resume(encoder, model) bind(c, name="gsenc_encoder_resume")
            import :: c_int, c_ptr
            type(c_ptr), value :: encoder, model
        end function
        integer(c_int) function gsenc_encoder_resume_stored_c(encoder, field, step) &
                bind(c, name="gsenc_encoder_resume_stored")
            import :: c_int, c_ptr, c_char, c_int64_t
            type(c_ptr), value :: encoder
            character(kind=c_char), intent(in) :: field(*)
            integer(c_int64_t), value :: step
        end function
        integer(c_int) function gsenc_encoder_write_model_c(encoder, field, path) &
                bind(c, name="gsenc_encoder_write_model")
            import :: c_int, c_ptr, c_char
            type(c_ptr), value :: encoder
            character(kind=c_char), intent(in) :: field(*), path(*)
        end function
        integer(c_int) function gsenc_encoder_last_step_c(encoder, field, step, psnr) &
                bind(c, name="gsenc_encoder_last_step")
            import :: c_int, c_ptr, c_char, c_int64_t, c_double
            type(c_ptr), value :: encoder
            character(kind=c_char), intent(in) :: field(*)
            integer(c_int64_t), intent(out) :: step
            real(c_double), intent(out) :: psnr
        end function
        integer(c_int) function gsenc_model_read_c(path, out) bind(c, name="gsenc_model_read")
            import :: c_int, c_ptr, c_char
            character(kind=c_char), intent(in) :: path(*)
            type(c_ptr), intent(out) :: out
        end function
        subroutine gsenc_model_destroy_c(model) bind(c, name="gsenc_model_destroy")
            import :: c_ptr
            type(c_ptr), value :: model
        end subroutine
        integer(c_int) function gsenc_model_info_get_c(model, info) bind(c, name="gsenc_model_info_get")
            import :: c_int, c_ptr, gsenc_model_info
            type(c_ptr), value :: model
            type(gsenc_model_info), intent(inout) :: info
        end function
        integer(c_int) function gsenc_model_decode_c(model, dims, out, out_len) bind(c, name="gsenc_model_decode")
            import :: c_int, c_ptr, c_int64_t
            type(c_ptr), value :: model, dims, out
            integer(c_int64_t), value :: out_len
        end function
        integer(c_int) function gsenc_model_evaluate_c(model, points, count, out) bind(c, name="gsenc_model_evaluate")
            import :: c_int, c_ptr, c_int64_t
            type(c_ptr), value :: model, points, out
            integer(c_int64_t), value :: count
        end function
        subroutine gsenc_set_last_error_c(message) bind(c, name="gsenc_set_last_error")
            import :: c_char
            character(kind=c_char), intent(in) :: message(*)
        end subroutine
        integer(c_size_t) function gsenc_last_error_c(buf, len) bind(c, name="gsenc_last_error")
            import :: c_size_t, c_ptr
            type(c_ptr), value :: buf
            integer(c_size_t), value :: len
        end function
    end interface

    public :: gsenc_version, gsenc_encoder_cancel, gsenc_encoder_reserve, gsenc_encoder_resume
    public :: gsenc_encoder_resume_stored_c, gsenc_encoder_resume_stored
    public :: gsenc_encoder_create_mpi_c, gsenc_encoder_create_mpi
    public :: gsenc_config_init_c, gsenc_encoder_create_c, gsenc_wait_c, gsenc_poll_c, gsenc_encoder_destroy_c, gsenc_push_grid_c, &
        gsenc_push_particles_c, gsenc_push_cells_c, gsenc_encoder_write_model_c, gsenc_encoder_last_step_c, &
        gsenc_model_read_c, gsenc_model_destroy_c, gsenc_model_info_get_c, gsenc_model_decode_c, &
        gsenc_model_evaluate_c, gsenc_last_error_c
    public :: gsenc_config_default, gsenc_encoder_create, gsenc_encoder_destroy, gsenc_wait, gsenc_poll, gsenc_push_grid, &
        gsenc_push_particles, gsenc_push_cells_boxes, gsenc_push_cells_hexahedra, gsenc_encoder_write_model, &
        gsenc_encoder_last_step, gsenc_model_read, gsenc_model_destroy, gsenc_model_info_get, gsenc_model_decode, &
        gsenc_model_evaluate, gsenc_last_error_message

    !> Hands over one field of a step on a regular grid: values(i, j, k) of
    !> any real32 or real64 array or array section (strides are passed on).
    interface gsenc_push_grid
        module procedure push_grid_r4, push_grid_r8
    end interface
    !> SPH particles: positions(3, n), smoothing_length(n), values(n) and
    !> optionally mass(n), sections allowed (one component of a vector field).
    interface gsenc_push_particles
        module procedure push_particles_r4, push_particles_r8
    end interface
    !> AMR cells as boxes: centres(3, n), edges(3, n), values(n).
    interface gsenc_push_cells_boxes
        module procedure push_boxes_r4, push_boxes_r8
    end interface
    !> Unstructured hexahedra: points(3, np), connectivity(8, n) (0-based,
    !> VTK order, int64), values(n).
    interface gsenc_push_cells_hexahedra
        module procedure push_hexahedra_r4, push_hexahedra_r8
    end interface

    ! How a caller's array lies in memory: its first element, its count and
    ! strides in elements. Built by the kind-specific `*_r4`/`*_r8`
    ! functions below (the only code that sees the array's type), used by
    ! the kind-free push procedures.
    type :: scalars_t
        type(c_ptr) :: first = c_null_ptr
        integer(c_int64_t) :: count = 0, stride = 1
    end type
    ! A (components, count) array of tuples.
    type :: tuples_t
        type(c_ptr) :: first = c_null_ptr
        integer(c_int64_t) :: components = 0, count = 0, stride = 1, component_stride = 1
    end type

contains

    !> A NUL-terminated copy of a Fortran string (trailing blanks dropped).
    pure function c_string(s) result(c)
        character(len=*), intent(in) :: s
        character(kind=c_char) :: c(len_trim(s) + 1)
        integer :: i
        do i = 1, len_trim(s)
            c(i) = s(i:i)
        end do
        c(len_trim(s) + 1) = c_null_char
    end function

    !> The address of a C pointer, for stride arithmetic.
    integer(c_intptr_t) function address(p)
        type(c_ptr), intent(in) :: p
        address = transfer(p, address)
    end function

    !> Elements between two addresses, for elements of `size` bytes.
    integer(c_int64_t) function elements(from, to, size)
        type(c_ptr), intent(in) :: from, to
        integer, intent(in) :: size
        elements = int((address(to) - address(from)) / size, c_int64_t)
    end function

    real(c_double) function time_or_nan(time)
        real(c_double), intent(in), optional :: time
        if (present(time)) then
            time_or_nan = time
        else
            time_or_nan = ieee_value(time_or_nan, ieee_quiet_nan)
        end if
    end function

    !> The defaults of gsenc_config_init, with struct_size set.
    function gsenc_config_default() result(config)
        type(gsenc_config) :: config
        integer(c_int) :: status
        config%struct_size = c_sizeof(config)
        status = gsenc_config_init_c(config)
    end function

    !> Creates an encoder from `config`; `output_dir`, when given, is the
    !> folder every model is written to as FIELD_STEP.gsm.
    integer(c_int) function gsenc_encoder_create(config, encoder, output_dir) result(status)
        type(gsenc_config), intent(in) :: config
        type(c_ptr), intent(out) :: encoder
        character(len=*), intent(in), optional :: output_dir
        type(gsenc_config) :: c
        character(kind=c_char), allocatable, target :: dir(:)
        call with_output_dir(config, output_dir, c, dir)
        status = gsenc_encoder_create_c(c, encoder)
    end function

    !> `config` with `output_dir` (when present) as a C string in `dir`,
    !> which must live until the create call returns.
    subroutine with_output_dir(config, output_dir, c, dir)
        type(gsenc_config), intent(in) :: config
        character(len=*), intent(in), optional :: output_dir
        type(gsenc_config), intent(out) :: c
        character(kind=c_char), allocatable, target, intent(inout) :: dir(:)
        c = config
        c%output_dir = c_null_ptr
        if (present(output_dir)) then
            allocate (dir(len_trim(output_dir) + 1))
            dir(:) = c_string(output_dir)
            c%output_dir = c_loc(dir)
        end if
    end subroutine

    !> Creates one rank's encoder of a domain-decomposed run over `comm`
    !> (an MPI communicator as the integer of `use mpi`, or `comm%MPI_VAL`
    !> of `use mpi_f08`). Collective, as are every push and
    !> gsenc_encoder_destroy of this encoder (and gsenc_wait when it writes
    !> an HDF5 store). Rank 0 writes each step's index FIELD_STEP.gsi into
    !> `output_dir`, or, with GSENC_OUTPUT_HDF5, every rank's models and
    !> each step's index into the store `output_dir`.
    integer(c_int) function gsenc_encoder_create_mpi(config, comm, encoder, output_dir) result(status)
        type(gsenc_config), intent(in) :: config
        integer, intent(in) :: comm
        type(c_ptr), intent(out) :: encoder
        character(len=*), intent(in), optional :: output_dir
        type(gsenc_config) :: c
        character(kind=c_char), allocatable, target :: dir(:)
        call with_output_dir(config, output_dir, c, dir)
        status = gsenc_encoder_create_mpi_c(c, int(comm, c_int32_t), encoder)
    end function

    !> Frees the encoder and sets the handle to c_null_ptr.
    subroutine gsenc_encoder_destroy(encoder)
        type(c_ptr), intent(inout) :: encoder
        call gsenc_encoder_destroy_c(encoder)
        encoder = c_null_ptr
    end subroutine

    type(scalars_t) function scalars_r4(a) result(d)
        real(real32), intent(in), target :: a(:)
        d%count = size(a, kind=c_int64_t)
        if (d%count > 0) d%first = c_loc(a(1))
        if (d%count > 1) d%stride = elements(d%first, c_loc(a(2)), 4)
    end function

    type(scalars_t) function scalars_r8(a) result(d)
        real(real64), intent(in), target :: a(:)
        d%count = size(a, kind=c_int64_t)
        if (d%count > 0) d%first = c_loc(a(1))
        if (d%count > 1) d%stride = elements(d%first, c_loc(a(2)), 8)
    end function

    type(tuples_t) function tuples_r4(a) result(d)
        real(real32), intent(in), target :: a(:, :)
        d%components = size(a, 1, kind=c_int64_t)
        d%count = size(a, 2, kind=c_int64_t)
        if (size(a) == 0) return
        d%first = c_loc(a(1, 1))
        if (d%components > 1) d%component_stride = elements(d%first, c_loc(a(2, 1)), 4)
        if (d%count > 1) d%stride = elements(d%first, c_loc(a(1, 2)), 4)
    end function

    type(tuples_t) function tuples_r8(a) result(d)
        real(real64), intent(in), target :: a(:, :)
        d%components = size(a, 1, kind=c_int64_t)
        d%count = size(a, 2, kind=c_int64_t)
        if (size(a) == 0) return
        d%first = c_loc(a(1, 1))
        if (d%components > 1) d%component_stride = elements(d%first, c_loc(a(2, 1)), 8)
        if (d%count > 1) d%stride = elements(d%first, c_loc(a(1, 2)), 8)
    end function

    integer(c_int) function push_grid_r4(encoder, field, step, values, origin, spacing, time) result(status)
        type(c_ptr), intent(in) :: encoder
        character(len=*), intent(in) :: field
        integer(int64), intent(in) :: step
        real(real32), intent(in), target :: values(:, :, :)
        real(c_double), intent(in) :: origin(3), spacing
        real(c_double), intent(in), optional :: time
        type(c_ptr) :: corners(4)
        corners = c_null_ptr
        if (size(values) > 0) corners = [c_loc(values(1, 1, 1)), c_loc(values(min(2, size(values, 1)), 1, 1)), &
            c_loc(values(1, min(2, size(values, 2)), 1)), c_loc(values(1, 1, min(2, size(values, 3))))]
        status = push_grid_any(encoder, field, step, GSENC_DTYPE_FLOAT32, 4, shape(values, kind=c_int64_t), corners, &
            origin, spacing, time)
    end function

    integer(c_int) function push_grid_r8(encoder, field, step, values, origin, spacing, time) result(status)
        type(c_ptr), intent(in) :: encoder
        character(len=*), intent(in) :: field
        integer(int64), intent(in) :: step
        real(real64), intent(in), target :: values(:, :, :)
        real(c_double), intent(in) :: origin(3), spacing
        real(c_double), intent(in), optional :: time
        type(c_ptr) :: corners(4)
        corners = c_null_ptr
        if (size(values) > 0) corners = [c_loc(values(1, 1, 1)), c_loc(values(min(2, size(values, 1)), 1, 1)), &
            c_loc(values(1, min(2, size(values, 2)), 1)), c_loc(values(1, 1, min(2, size(values, 3))))]
        status = push_grid_any(encoder, field, step, GSENC_DTYPE_FLOAT64, 8, shape(values, kind=c_int64_t), corners, &
            origin, spacing, time)
    end function

    !> A grid push from the addresses of elements (1,1,1), (2,1,1), (1,2,1)
    !> and (1,1,2): their differences are the memory strides. An axis of
    !> extent 1 gets stride 1 (never used), not the "all zero" default.
    integer(c_int) function push_grid_any(encoder, field, step, dtype, size, extents, corners, origin, spacing, time) &
            result(status)
        type(c_ptr), intent(in) :: encoder
        character(len=*), intent(in) :: field
        integer(int64), intent(in) :: step
        integer(c_int32_t), intent(in) :: dtype
        integer, intent(in) :: size
        integer(c_int64_t), intent(in) :: extents(3)
        type(c_ptr), intent(in) :: corners(4)
        real(c_double), intent(in) :: origin(3), spacing
        real(c_double), intent(in), optional :: time
        type(gsenc_grid) :: g
        integer :: a
        g%struct_size = c_sizeof(g)
        g%dtype = dtype
        g%extents = extents
        g%origin = origin
        g%spacing = spacing
        g%data = corners(1)
        g%strides = 1
        if (c_associated(corners(1))) then
            do a = 1, 3
                if (extents(a) > 1) g%strides(a) = elements(corners(1), corners(a + 1), size)
            end do
        end if
        status = gsenc_push_grid_c(encoder, c_string(field), int(step, c_int64_t), time_or_nan(time), g)
    end function

    !> Whether two array lengths agree; records `what` as the error if not.
    logical function shapes_agree(what, n, m)
        character(len=*), intent(in) :: what
        integer(c_int64_t), intent(in) :: n, m
        shapes_agree = n == m
        if (.not. shapes_agree) call set_error(what)
    end function

    !> Records a Fortran-side argument error as the thread's last error.
    subroutine set_error(what)
        character(len=*), intent(in) :: what
        call gsenc_set_last_error_c(c_string(what))
    end subroutine

    !> Whether `t` is (3, n), n the values' count; records the error if not.
    logical function triples_of(what, t, n)
        character(len=*), intent(in) :: what
        type(tuples_t), intent(in) :: t
        integer(c_int64_t), intent(in) :: n
        triples_of = t%components == 3 .and. t%count == n
        if (.not. triples_of) call set_error(what)
    end function

    integer(c_int) function push_particles_r4(encoder, field, step, positions, smoothing_length, values, mass, time) &
            result(status)
        type(c_ptr), intent(in) :: encoder
        character(len=*), intent(in) :: field
        integer(int64), intent(in) :: step
        real(real32), intent(in), target :: positions(:, :), smoothing_length(:), values(:)
        real(real32), intent(in), target, optional :: mass(:)
        real(c_double), intent(in), optional :: time
        type(scalars_t) :: m
        if (present(mass)) m = scalars_r4(mass)
        status = push_particles_any(encoder, field, step, GSENC_DTYPE_FLOAT32, tuples_r4(positions), &
            scalars_r4(smoothing_length), scalars_r4(values), present(mass), m, time)
    end function

    integer(c_int) function push_particles_r8(encoder, field, step, positions, smoothing_length, values, mass, time) &
            result(status)
        type(c_ptr), intent(in) :: encoder
        character(len=*), intent(in) :: field
        integer(int64), intent(in) :: step
        real(real64), intent(in), target :: positions(:, :), smoothing_length(:), values(:)
        real(real64), intent(in), target, optional :: mass(:)
        real(c_double), intent(in), optional :: time
        type(scalars_t) :: m
        if (present(mass)) m = scalars_r8(mass)
        status = push_particles_any(encoder, field, step, GSENC_DTYPE_FLOAT64, tuples_r8(positions), &
            scalars_r8(smoothing_length), scalars_r8(values), present(mass), m, time)
    end function

    integer(c_int) function push_particles_any(encoder, field, step, dtype, positions, h, values, has_mass, mass, time) &
            result(status)
        type(c_ptr), intent(in) :: encoder
        character(len=*), intent(in) :: field
        integer(int64), intent(in) :: step
        integer(c_int32_t), intent(in) :: dtype
        type(tuples_t), intent(in) :: positions
        type(scalars_t), intent(in) :: h, values, mass
        logical, intent(in) :: has_mass
        real(c_double), intent(in), optional :: time
        type(gsenc_particles) :: p
        status = GSENC_STATUS_INVALID_ARGUMENT
        if (.not. triples_of("gsenc_push_particles: positions must be (3, n), n the values' count", positions, values%count)) &
            return
        if (.not. shapes_agree("gsenc_push_particles: smoothing_length and values differ in length", values%count, h%count)) &
            return
        if (has_mass) then
            if (.not. shapes_agree("gsenc_push_particles: mass and values differ in length", values%count, mass%count)) return
        end if
        p%struct_size = c_sizeof(p)
        p%dtype = dtype
        p%count = values%count
        p%positions = positions%first
        p%position_stride = positions%stride
        p%position_component_stride = positions%component_stride
        p%smoothing_length = h%first
        p%smoothing_length_stride = h%stride
        p%values = values%first
        p%value_stride = values%stride
        if (has_mass) then
            p%mass = mass%first
            p%mass_stride = mass%stride
        end if
        status = gsenc_push_particles_c(encoder, c_string(field), int(step, c_int64_t), time_or_nan(time), p)
    end function

    integer(c_int) function push_boxes_r4(encoder, field, step, centres, edges, values, time) result(status)
        type(c_ptr), intent(in) :: encoder
        character(len=*), intent(in) :: field
        integer(int64), intent(in) :: step
        real(real32), intent(in), target :: centres(:, :), edges(:, :), values(:)
        real(c_double), intent(in), optional :: time
        status = push_boxes_any(encoder, field, step, GSENC_DTYPE_FLOAT32, tuples_r4(centres), tuples_r4(edges), &
            scalars_r4(values), time)
    end function

    integer(c_int) function push_boxes_r8(encoder, field, step, centres, edges, values, time) result(status)
        type(c_ptr), intent(in) :: encoder
        character(len=*), intent(in) :: field
        integer(int64), intent(in) :: step
        real(real64), intent(in), target :: centres(:, :), edges(:, :), values(:)
        real(c_double), intent(in), optional :: time
        status = push_boxes_any(encoder, field, step, GSENC_DTYPE_FLOAT64, tuples_r8(centres), tuples_r8(edges), &
            scalars_r8(values), time)
    end function

    integer(c_int) function push_boxes_any(encoder, field, step, dtype, centres, edges, values, time) result(status)
        type(c_ptr), intent(in) :: encoder
        character(len=*), intent(in) :: field
        integer(int64), intent(in) :: step
        integer(c_int32_t), intent(in) :: dtype
        type(tuples_t), intent(in) :: centres, edges
        type(scalars_t), intent(in) :: values
        real(c_double), intent(in), optional :: time
        type(gsenc_cells) :: c
        status = GSENC_STATUS_INVALID_ARGUMENT
        if (.not. triples_of("gsenc_push_cells_boxes: centres must be (3, n), n the values' count", centres, values%count)) &
            return
        if (.not. triples_of("gsenc_push_cells_boxes: edges must be (3, n), n the values' count", edges, values%count)) return
        c%struct_size = c_sizeof(c)
        c%dtype = dtype
        c%layout = GSENC_CELLS_BOXES
        c%count = values%count
        c%centres = centres%first
        c%centre_stride = centres%stride
        c%centre_component_stride = centres%component_stride
        c%edges = edges%first
        c%edge_stride = edges%stride
        c%edge_component_stride = edges%component_stride
        c%values = values%first
        c%value_stride = values%stride
        status = gsenc_push_cells_c(encoder, c_string(field), int(step, c_int64_t), time_or_nan(time), c)
    end function

    integer(c_int) function push_hexahedra_r4(encoder, field, step, points, connectivity, values, time) result(status)
        type(c_ptr), intent(in) :: encoder
        character(len=*), intent(in) :: field
        integer(int64), intent(in) :: step
        real(real32), intent(in), target :: points(:, :), values(:)
        integer(c_int64_t), intent(in), target, contiguous :: connectivity(:, :)
        real(c_double), intent(in), optional :: time
        status = push_hexahedra_any(encoder, field, step, GSENC_DTYPE_FLOAT32, tuples_r4(points), connectivity, &
            scalars_r4(values), time)
    end function

    integer(c_int) function push_hexahedra_r8(encoder, field, step, points, connectivity, values, time) result(status)
        type(c_ptr), intent(in) :: encoder
        character(len=*), intent(in) :: field
        integer(int64), intent(in) :: step
        real(real64), intent(in), target :: points(:, :), values(:)
        integer(c_int64_t), intent(in), target, contiguous :: connectivity(:, :)
        real(c_double), intent(in), optional :: time
        status = push_hexahedra_any(encoder, field, step, GSENC_DTYPE_FLOAT64, tuples_r8(points), connectivity, &
            scalars_r8(values), time)
    end function

    integer(c_int) function push_hexahedra_any(encoder, field, step, dtype, points, connectivity, values, time) &
            result(status)
        type(c_ptr), intent(in) :: encoder
        character(len=*), intent(in) :: field
        integer(int64), intent(in) :: step
        integer(c_int32_t), intent(in) :: dtype
        type(tuples_t), intent(in) :: points
        integer(c_int64_t), intent(in), target, contiguous :: connectivity(:, :)
        type(scalars_t), intent(in) :: values
        real(c_double), intent(in), optional :: time
        type(gsenc_cells) :: c
        status = GSENC_STATUS_INVALID_ARGUMENT
        if (points%components /= 3 .or. size(connectivity, 1) /= 8) then
            call set_error("gsenc_push_cells_hexahedra: points must be (3, np) and connectivity (8, n)")
            return
        end if
        if (.not. shapes_agree("gsenc_push_cells_hexahedra: connectivity and values differ in length", &
                values%count, size(connectivity, 2, kind=c_int64_t))) return
        c%struct_size = c_sizeof(c)
        c%dtype = dtype
        c%layout = GSENC_CELLS_HEXAHEDRA
        c%count = values%count
        c%point_count = points%count
        c%points = points%first
        c%point_stride = points%stride
        c%point_component_stride = points%component_stride
        if (values%count > 0) c%connectivity = c_loc(connectivity(1, 1))
        c%values = values%first
        c%value_stride = values%stride
        status = gsenc_push_cells_c(encoder, c_string(field), int(step, c_int64_t), time_or_nan(time), c)
    end function

    !> Blocks until every pushed step of `field` (absent: of every field) is
    !> encoded and written; returns the first failure not reported before.
    integer(c_int) function gsenc_wait(encoder, field) result(status)
        type(c_ptr), intent(in) :: encoder
        character(len=*), intent(in), optional :: field
        character(kind=c_char), allocatable, target :: name(:)
        if (present(field)) then
            allocate (name(len_trim(field) + 1))
            name(:) = c_string(field)
            status = gsenc_wait_c(encoder, c_loc(name))
        else
            status = gsenc_wait_c(encoder, c_null_ptr)
        end if
    end function

    !> The state of `field`'s step `step` (GSENC_JOB_*), without waiting.
    integer(c_int) function gsenc_poll(encoder, field, step, job) result(status)
        type(c_ptr), intent(in) :: encoder
        character(len=*), intent(in) :: field
        integer(int64), intent(in) :: step
        type(gsenc_job), intent(out) :: job
        job%struct_size = c_sizeof(job)
        status = gsenc_poll_c(encoder, c_string(field), int(step, c_int64_t), job)
    end function

    integer(c_int) function gsenc_encoder_write_model(encoder, field, path) result(status)
        type(c_ptr), intent(in) :: encoder
        character(len=*), intent(in) :: field, path
        status = gsenc_encoder_write_model_c(encoder, c_string(field), c_string(path))
    end function

    !> Continues `field`'s series from its step `step` as the encoder's own
    !> output (folder or store) holds it: a restart (before the field's first
    !> push; collective on an MPI encoder).
    integer(c_int) function gsenc_encoder_resume_stored(encoder, field, step) result(status)
        type(c_ptr), intent(in) :: encoder
        character(len=*), intent(in) :: field
        integer(int64), intent(in) :: step
        status = gsenc_encoder_resume_stored_c(encoder, c_string(field), int(step, c_int64_t))
    end function

    integer(c_int) function gsenc_encoder_last_step(encoder, field, step, psnr) result(status)
        type(c_ptr), intent(in) :: encoder
        character(len=*), intent(in) :: field
        integer(int64), intent(out) :: step
        real(c_double), intent(out) :: psnr
        integer(c_int64_t) :: s
        status = gsenc_encoder_last_step_c(encoder, c_string(field), s, psnr)
        step = s
    end function

    integer(c_int) function gsenc_model_read(path, model) result(status)
        character(len=*), intent(in) :: path
        type(c_ptr), intent(out) :: model
        status = gsenc_model_read_c(c_string(path), model)
    end function

    !> Frees the model and sets the handle to c_null_ptr.
    subroutine gsenc_model_destroy(model)
        type(c_ptr), intent(inout) :: model
        call gsenc_model_destroy_c(model)
        model = c_null_ptr
    end subroutine

    integer(c_int) function gsenc_model_info_get(model, info) result(status)
        type(c_ptr), intent(in) :: model
        type(gsenc_model_info), intent(out) :: info
        info%struct_size = c_sizeof(info)
        status = gsenc_model_info_get_c(model, info)
    end function

    !> Decodes onto out(nx, ny, nz) cells covering the model's box (any
    !> shape: the model is resampled), in data units. `out` must be
    !> contiguous (decode into a whole array, then copy a section).
    integer(c_int) function gsenc_model_decode(model, out) result(status)
        type(c_ptr), intent(in) :: model
        real(real32), intent(inout), target :: out(:, :, :)
        integer(c_int64_t), target :: dims(3)
        if (.not. is_contiguous(out)) then
            call set_error("gsenc_model_decode: out must be a contiguous array")
            status = GSENC_STATUS_INVALID_ARGUMENT
            return
        end if
        dims = shape(out, kind=c_int64_t)
        if (size(out) == 0) then
            status = gsenc_model_decode_c(model, c_loc(dims), c_null_ptr, 0_c_int64_t)
        else
            status = gsenc_model_decode_c(model, c_loc(dims), c_loc(out(1, 1, 1)), size(out, kind=c_int64_t))
        end if
    end function

    !> Evaluates the model at world points(3, n) into out(n), data units.
    integer(c_int) function gsenc_model_evaluate(model, points, out) result(status)
        type(c_ptr), intent(in) :: model
        real(real64), intent(in), target, contiguous :: points(:, :)
        real(real32), intent(inout), target, contiguous :: out(:)
        status = GSENC_STATUS_INVALID_ARGUMENT
        if (size(points, 1) /= 3) then
            call set_error("gsenc_model_evaluate: points must be (3, n)")
            return
        end if
        if (.not. shapes_agree("gsenc_model_evaluate: points and out differ in length", &
                size(points, 2, kind=c_int64_t), size(out, kind=c_int64_t))) return
        if (size(out) == 0) then
            status = gsenc_model_evaluate_c(model, c_null_ptr, 0_c_int64_t, c_null_ptr)
        else
            status = gsenc_model_evaluate_c(model, c_loc(points(1, 1)), size(out, kind=c_int64_t), c_loc(out(1)))
        end if
    end function

    !> The calling thread's last error message ("" when none).
    function gsenc_last_error_message() result(message)
        character(len=:), allocatable :: message
        character(kind=c_char), allocatable, target :: buf(:)
        integer(c_size_t) :: n
        integer :: i
        n = gsenc_last_error_c(c_null_ptr, 0_c_size_t)
        allocate (buf(n + 1))
        n = gsenc_last_error_c(c_loc(buf), n + 1)
        allocate (character(len=n) :: message)
        do i = 1, int(n)
            message(i:i) = buf(i)
        end do
    end function
end module gsenc
