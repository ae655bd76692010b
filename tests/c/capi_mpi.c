/* The MPI side of the C API, run under mpirun -n 1, 2 and 4 (tests/mpi.sh):
 * errors before MPI_Init, a collective create over MPI_Comm_c2f, each rank
 * pushing its slab of a grid and its particles for two steps, the step index
 * and every rank's model written, misuse and a rank short of memory reported
 * on every rank, the caller's communicator untouched after destroy, and the
 * same grid steps written into one HDF5 store by rank 0 (OUTPUT_DIR/run.h5,
 * which tests/mpi.sh compares with the folder's models), a store rank 0
 * cannot open failing every rank's create, as do ranks asking for different
 * outputs, a write that fails on rank 0 reported by every rank's wait, a
 * rank with no particles (refused at a field's first step, taken later), a
 * rank's negative smoothing length and a rank's refused arguments at create
 * failing every rank together. */
#define _POSIX_C_SOURCE 200112L /* setenv */
#include "gsenc.h"
#include "mpi_checks.h"
#include <math.h>
#include <mpi.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define N 24

/* This process's resident memory in bytes (VmRSS), or -1. */
static long resident_bytes(void) {
    FILE *f = fopen("/proc/self/status", "r");
    char line[256];
    long kib = -1;
    while (f && fgets(line, sizeof line, f))
        if (sscanf(line, "VmRSS: %ld kB", &kib) == 1) break;
    if (f) fclose(f);
    return kib < 0 ? -1 : kib * 1024;
}

int main(int argc, char **argv) {
    if (argc < 2) {
        fprintf(stderr, "usage: capi_mpi OUTPUT_DIR\n");
        return 2;
    }
    gsenc_config cfg;
    cfg.struct_size = sizeof cfg;
    gsenc_config_init(&cfg);
    cfg.budget = 150;
    cfg.iterations = 60;
    cfg.warm_iterations = 30;
    cfg.dims[0] = cfg.dims[1] = cfg.dims[2] = N;
    cfg.halo = 4;
    cfg.output_dir = argv[1];
    /* Packed: each model packed at the precision its encode measured, which
     * rank 0 must receive with the model to store it the same. */
    cfg.payload = GSENC_PAYLOAD_PACKED;
    CHECK(cfg.halo == 4, "halo is a config field");

    /* Before MPI_Init: a clear error, no handle. */
    gsenc_encoder *enc = (gsenc_encoder *)1;
    EXPECT(gsenc_encoder_create_mpi(&cfg, 0, &enc), GSENC_STATUS_MPI);
    CHECK(enc == NULL && strstr(last_error(), "not initialised") != NULL, "before MPI_Init: %s", last_error());

    int provided = 0;
    MPI_Init_thread(&argc, &argv, MPI_THREAD_FUNNELED, &provided);
    int size = 1;
    MPI_Comm_rank(MPI_COMM_WORLD, &rank);
    MPI_Comm_size(MPI_COMM_WORLD, &size);
    CHECK(provided >= MPI_THREAD_FUNNELED, "MPI gave thread level %d", provided);
    /* The world's duplicate, to show that gsenc frees only its own. */
    MPI_Comm comm;
    MPI_Comm_dup(MPI_COMM_WORLD, &comm);
    EXPECT(gsenc_encoder_create_mpi(&cfg, MPI_Comm_c2f(comm), NULL), GSENC_STATUS_NULL_POINTER);
    EXPECT(gsenc_encoder_create_mpi(&cfg, MPI_Comm_c2f(comm), &enc), GSENC_STATUS_OK);

    /* Slabs along x: rank r owns x cells [r*N/size, (r+1)*N/size). */
    int x0 = rank * N / size, x1 = (rank + 1) * N / size, nx = x1 - x0;
    float *slab = malloc(sizeof(float) * (size_t)nx * N * N);
    double *pos = malloc(sizeof(double) * 3 * 4096), *hh = malloc(sizeof(double) * 4096), *val = malloc(sizeof(double) * 4096);
    for (int step = 1; step <= 2; step++) {
        fill_slab(slab, N, x0, nx, step);
        gsenc_grid g = {sizeof g, GSENC_DTYPE_FLOAT32, slab, {(uint64_t)nx, N, N}, {0, 0, 0}, {(double)x0 / N, 0, 0}, 1.0 / N};
        EXPECT(gsenc_push_grid(enc, "rho", (uint64_t)step, step * 0.1, &g), GSENC_STATUS_OK);
        /* Particles on a lattice, each rank its own x range. */
        gsenc_particles p = lattice_particles(16, size, 0.0, step, pos, hh, val);
        EXPECT(gsenc_push_particles(enc, "tracer", (uint64_t)step, step * 0.1, &p), GSENC_STATUS_OK);
    }
    EXPECT(gsenc_wait(enc, NULL), GSENC_STATUS_OK);

    /* A field keeps its form: rho came as a grid, particles are refused on every rank. */
    {
        gsenc_particles p;
        memset(&p, 0, sizeof p);
        p.struct_size = sizeof p;
        p.dtype = GSENC_DTYPE_FLOAT64;
        p.count = 1;
        p.positions = pos;
        p.smoothing_length = hh;
        p.values = val;
        pos[0] = pos[1] = pos[2] = (rank + 0.5) / size;
        hh[0] = 0.1, val[0] = 1.0;
        EXPECT(gsenc_push_particles(enc, "rho", 3, 0.3, &p), GSENC_STATUS_INVALID_ARGUMENT);
        CHECK(strstr(last_error(), "came as a grid") != NULL, "form change: %s", last_error());
    }
    /* Grids of different spacings cannot share one lattice: every rank hears of it. */
    if (size > 1) {
        gsenc_grid g = {sizeof g, GSENC_DTYPE_FLOAT32, slab, {(uint64_t)nx, N, N}, {0, 0, 0}, {(double)x0 / N, 0, 0}, 1.0 / (N + rank)};
        EXPECT(gsenc_push_grid(enc, "spacing", 1, 0.0, &g), GSENC_STATUS_MPI);
        CHECK(strstr(last_error(), "spacings") != NULL, "spacing mismatch: %s", last_error());
    }

    /* Misuse: the ranks push different steps; every rank hears of it. */
    if (size > 1) {
        gsenc_grid g = {sizeof g, GSENC_DTYPE_FLOAT32, slab, {(uint64_t)nx, N, N}, {0, 0, 0}, {(double)x0 / N, 0, 0}, 1.0 / N};
        EXPECT(gsenc_push_grid(enc, "rho", (uint64_t)(3 + rank), 0.3, &g), GSENC_STATUS_MPI);
        CHECK(strstr(last_error(), "different") != NULL, "misuse message: %s", last_error());
        /* One rank's NaN: that rank gets INVALID_DATA, the others MPI naming it. */
        if (rank == size - 1) slab[5] = NAN;
        gsenc_status s = gsenc_push_grid(enc, "rho", 3, 0.3, &g);
        if (rank == size - 1)
            CHECK(s == GSENC_STATUS_INVALID_DATA, "NaN rank got %s", gsenc_status_string(s));
        else
            CHECK(s == GSENC_STATUS_MPI && strstr(last_error(), "refused") != NULL, "other rank got %s: %s", gsenc_status_string(s), last_error());
        slab[5] = 0.0f;
        /* One rank cannot take its copy (GSENC_MEMORY_LIMIT there): that
         * rank gets INVALID_ARGUMENT, the others MPI naming it, and no rank
         * waits in the push for another. */
        if (rank == 0) setenv("GSENC_MEMORY_LIMIT", "1M", 1);
        s = gsenc_push_grid(enc, "rho", 3, 0.3, &g);
        if (rank == 0) {
            CHECK(s == GSENC_STATUS_INVALID_ARGUMENT && strstr(last_error(), "the field's copy takes") != NULL, "short rank got %s: %s", gsenc_status_string(s), last_error());
            unsetenv("GSENC_MEMORY_LIMIT");
        } else {
            CHECK(s == GSENC_STATUS_MPI && strstr(last_error(), "rank 0 refused") != NULL, "other rank got %s: %s", gsenc_status_string(s), last_error());
        }
        /* One rank has room for its copy of a larger grid but not for the
         * exchange (what it sends and receives, as doubles, and its joined
         * piece: about five copies): that rank gets INVALID_ARGUMENT naming
         * the exchange, the others MPI naming it, before any buffer of the
         * exchange is allocated. */
        {
            const int bx = 64, bn = 128;
            float *big = malloc(sizeof(float) * (size_t)bx * bn * bn);
            for (size_t i = 0; i < (size_t)bx * bn * bn; i++) big[i] = (float)(i % 977);
            gsenc_grid gb = {sizeof gb, GSENC_DTYPE_FLOAT32, big, {(uint64_t)bx, bn, bn}, {0, 0, 0}, {(double)(rank * bx) / bn, 0, 0}, 1.0 / bn};
            long rss = resident_bytes();
            CHECK(rss > 0, "VmRSS of /proc/self/status");
            if (rank == 0) {
                /* The copy (4 MB) fits in 12 MB more than now; the exchange (about 21 MB) does not. */
                char limit[32];
                snprintf(limit, sizeof limit, "%ld", rss + (12L << 20));
                setenv("GSENC_MEMORY_LIMIT", limit, 1);
            }
            s = gsenc_push_grid(enc, "big", 1, 0.0, &gb);
            if (rank == 0) {
                CHECK(s == GSENC_STATUS_INVALID_ARGUMENT && strstr(last_error(), "exchanging this rank's piece takes") != NULL, "short rank got %s: %s", gsenc_status_string(s), last_error());
                unsetenv("GSENC_MEMORY_LIMIT");
            } else {
                CHECK(s == GSENC_STATUS_MPI && strstr(last_error(), "rank 0 refused to exchange") != NULL, "other rank got %s: %s", gsenc_status_string(s), last_error());
            }
            free(big);
        }
        /* The encoder goes on: step 3 again, everywhere. */
        EXPECT(gsenc_push_grid(enc, "rho", 3, 0.3, &g), GSENC_STATUS_OK);
        EXPECT(gsenc_wait(enc, NULL), GSENC_STATUS_OK);
    }
    gsenc_encoder_destroy(enc);

    /* A rank with no particles: refused at a field's first step (a rank's
     * piece is where its data are), on every rank together; taken at later
     * steps, NULL arrays and all (an empty C++ vector's data()), the rank's
     * piece encoded from what its neighbours' particles reach of it, or
     * from nothing. Both were refused on every rank before (count 0),
     * failing the whole step; a piece that held no particle's centre
     * failed its rank's encode ("none of the items lies inside"). */
    if (size > 1) {
        int last = rank == size - 1;
        /* No halo: the last rank's piece is its own region alone, which at
         * step 2 holds no particle's centre, only its neighbours' reach, and
         * at step 4 (the others' particles tiny) not even that. */
        gsenc_config sparse = cfg;
        sparse.halo = 0;
        EXPECT(gsenc_encoder_create_mpi(&sparse, MPI_Comm_c2f(comm), &enc), GSENC_STATUS_OK);
        gsenc_particles p = lattice_particles(16, size, 0.0, 1, pos, hh, val), none = p;
        none.count = 0, none.positions = NULL, none.smoothing_length = NULL, none.values = NULL;
        gsenc_status s = gsenc_push_particles(enc, "sparse", 1, 0.1, last ? &none : &p);
        if (last)
            CHECK(s == GSENC_STATUS_INVALID_DATA && strstr(last_error(), "no particles at the field's first step") != NULL, "empty rank at the first step got %s: %s", gsenc_status_string(s), last_error());
        else
            CHECK(s == GSENC_STATUS_MPI && strstr(last_error(), "refused its data") != NULL, "other rank got %s: %s", gsenc_status_string(s), last_error());
        EXPECT(gsenc_push_particles(enc, "sparse", 1, 0.1, &p), GSENC_STATUS_OK);
        p = lattice_particles(16, size, 0.0, 2, pos, hh, val);
        EXPECT(gsenc_push_particles(enc, "sparse", 2, 0.2, last ? &none : &p), GSENC_STATUS_OK);
        /* A negative smoothing length on one rank is refused before its
         * particles go to the pieces they reach (it went nowhere, taken). */
        p = lattice_particles(16, size, 0.0, 3, pos, hh, val);
        if (rank == 0) hh[2] = -0.25;
        s = gsenc_push_particles(enc, "sparse", 3, 0.3, &p);
        if (rank == 0)
            CHECK(s == GSENC_STATUS_INVALID_DATA && strstr(last_error(), "particle 2 has smoothing length -0.25") != NULL, "negative smoothing length got %s: %s", gsenc_status_string(s), last_error());
        else
            CHECK(s == GSENC_STATUS_MPI && strstr(last_error(), "rank 0 refused") != NULL, "other rank got %s: %s", gsenc_status_string(s), last_error());
        p = lattice_particles(16, size, 0.0, 4, pos, hh, val);
        for (uint64_t i = 0; i < p.count; i++) hh[i] = 1e-3;
        EXPECT(gsenc_push_particles(enc, "sparse", 4, 0.4, last ? &none : &p), GSENC_STATUS_OK);
        EXPECT(gsenc_wait(enc, NULL), GSENC_STATUS_OK);
        gsenc_encoder_destroy(enc);
        /* Every rank's model of steps 2 and 4: its piece, of the budget. */
        for (int step = 2; step <= 4; step += 2) {
            char path[600];
            snprintf(path, sizeof path, "%s/sparse_%06d%s%.0d.gsm", argv[1], step, rank ? "_r" : "", rank);
            gsenc_model *m = NULL;
            EXPECT(gsenc_model_read(path, &m), GSENC_STATUS_OK);
            gsenc_model_info info;
            info.struct_size = sizeof info;
            EXPECT(gsenc_model_info_get(m, &info), GSENC_STATUS_OK);
            CHECK(info.step == (uint64_t)step && info.rank == (uint32_t)rank && info.count == cfg.budget, "%s: step %llu rank %u, %llu primitives", path, (unsigned long long)info.step, info.rank, (unsigned long long)info.count);
            gsenc_model_destroy(m);
        }
    }

    /* A rank whose arguments are refused (a zero budget; no handle slot)
     * fails with its own error and the others naming it: they waited for
     * it in the create's collectives before, for ever. */
    {
        gsenc_config bad = cfg;
        if (rank == size - 1) bad.budget = 0;
        enc = (gsenc_encoder *)1;
        gsenc_status s = gsenc_encoder_create_mpi(&bad, MPI_Comm_c2f(comm), &enc);
        CHECK(enc == NULL, "a failed create left a handle");
        if (rank == size - 1)
            CHECK(s == GSENC_STATUS_INVALID_ARGUMENT && strstr(last_error(), "budget") != NULL, "zero budget got %s: %s", gsenc_status_string(s), last_error());
        else
            CHECK(s == GSENC_STATUS_MPI && strstr(last_error(), "failed to read its arguments") != NULL, "other rank got %s: %s", gsenc_status_string(s), last_error());
        s = gsenc_encoder_create_mpi(&cfg, MPI_Comm_c2f(comm), rank == 0 ? NULL : &enc);
        if (rank == 0)
            CHECK(s == GSENC_STATUS_NULL_POINTER, "no handle slot got %s: %s", gsenc_status_string(s), last_error());
        else
            CHECK(s == GSENC_STATUS_MPI && strstr(last_error(), "rank 0 failed to read its arguments") != NULL && enc == NULL, "other rank got %s: %s", gsenc_status_string(s), last_error());
    }

    /* Particles in configured bounds wider than they fill: the pieces (the
     * data's box and halo) stop short of the lattice's faces, and the step
     * keeps the configured lattice (tests/mpi.sh decodes it). */
    {
        gsenc_config wide = cfg;
        wide.has_bounds = 1;
        for (int a = 0; a < 3; a++) wide.bounds_min[a] = -1.0, wide.bounds_max[a] = 2.0;
        EXPECT(gsenc_encoder_create_mpi(&wide, MPI_Comm_c2f(comm), &enc), GSENC_STATUS_OK);
        gsenc_particles p = lattice_particles(16, size, 0.0, 1, pos, hh, val);
        EXPECT(gsenc_push_particles(enc, "cloud", 1, 0.1, &p), GSENC_STATUS_OK);
        EXPECT(gsenc_wait(enc, NULL), GSENC_STATUS_OK);
        gsenc_encoder_destroy(enc);
    }

    /* One HDF5 store for every rank, written by rank 0 (tests/mpi.sh reads it). */
    {
        char store[1024];
        snprintf(store, sizeof store, "%s/run.h5", argv[1]);
        gsenc_config h5 = cfg;
        h5.output_format = GSENC_OUTPUT_HDF5;
        h5.output_dir = "/nonexistent-gsenc-dir/run.h5";
        gsenc_status s = gsenc_encoder_create_mpi(&h5, MPI_Comm_c2f(comm), &enc);
        if (rank == 0)
            CHECK(s == GSENC_STATUS_IO && enc == NULL, "rank 0 cannot create the store: %s: %s", gsenc_status_string(s), last_error());
        else
            CHECK(s == GSENC_STATUS_MPI && enc == NULL && strstr(last_error(), "rank 0 failed") != NULL, "the others hear of it: %s: %s", gsenc_status_string(s), last_error());
        h5.output_dir = store;
        /* Ranks that would write different ways (a store makes wait collective) are refused on every rank. */
        if (size > 1) {
            gsenc_config mixed = rank == 0 ? h5 : cfg;
            EXPECT(gsenc_encoder_create_mpi(&mixed, MPI_Comm_c2f(comm), &enc), GSENC_STATUS_MPI);
            CHECK(enc == NULL && strstr(last_error(), "different outputs") != NULL, "mixed outputs: %s", last_error());
        }
        for (int pass = 0; pass < 2; pass++) {
            /* The second pass pushes step 1 into the same store again, at
             * another time (so another index and other models: the same
             * ones would be taken as a restarted run's, and change nothing):
             * rank 0 cannot write the step's index (its push fails) nor any
             * rank's model (every rank's wait fails, naming the entry). */
            EXPECT(gsenc_encoder_create_mpi(&h5, MPI_Comm_c2f(comm), &enc), GSENC_STATUS_OK);
            for (int step = 1; step <= 2 - pass; step++) {
                fill_slab(slab, N, x0, nx, step);
                gsenc_grid g = {sizeof g, GSENC_DTYPE_FLOAT32, slab, {(uint64_t)nx, N, N}, {0, 0, 0}, {(double)x0 / N, 0, 0}, 1.0 / N};
                s = gsenc_push_grid(enc, "rho", (uint64_t)step, step * 0.1 + pass, &g);
                if (pass == 1 && rank == 0)
                    CHECK(s == GSENC_STATUS_INVALID_ARGUMENT && strstr(last_error(), "already holds a step index") != NULL &&
                              strstr(last_error(), "step 1 was queued on every rank") != NULL, "rank 0 pushing a stored step: %s: %s", gsenc_status_string(s), last_error());
                else
                    CHECK(s == GSENC_STATUS_OK, "store push of step %d: %s: %s", step, gsenc_status_string(s), last_error());
            }
            s = gsenc_wait(enc, NULL);
            if (pass == 0) {
                CHECK(s == GSENC_STATUS_OK, "store wait: %s: %s", gsenc_status_string(s), last_error());
                gsenc_job job;
                job.struct_size = sizeof job;
                EXPECT(gsenc_poll(enc, "rho", 2, &job), GSENC_STATUS_OK);
                CHECK(job.state == GSENC_JOB_DONE && job.psnr > 20, "step 2 stored: state %d psnr %g", job.state, job.psnr);
            } else {
                char entry[64];
                snprintf(entry, sizeof entry, "/rho/1/rank_%d already holds a model", rank);
                CHECK(s == GSENC_STATUS_INVALID_ARGUMENT && strstr(last_error(), entry) != NULL, "a write that failed on rank 0: %s: %s", gsenc_status_string(s), last_error());
                gsenc_job job;
                job.struct_size = sizeof job;
                EXPECT(gsenc_poll(enc, "rho", 1, &job), GSENC_STATUS_OK);
                CHECK(job.state == GSENC_JOB_FAILED && job.error == GSENC_STATUS_INVALID_ARGUMENT, "its step failed: state %d error %d", job.state, job.error);
            }
            gsenc_encoder_destroy(enc);
        }
    }

    /* The caller's communicator still works, and is the caller's to free. */
    int one = 1, sum = 0;
    CHECK(MPI_Allreduce(&one, &sum, 1, MPI_INT, MPI_SUM, comm) == MPI_SUCCESS && sum == size, "the caller's communicator after destroy");
    MPI_Comm_free(&comm);

    /* Every rank's model of step 2 is there, as that rank's, warm-started. */
    char path[1024];
    if (rank == 0)
        snprintf(path, sizeof path, "%s/rho_000002.gsm", argv[1]);
    else
        snprintf(path, sizeof path, "%s/rho_000002_r%d.gsm", argv[1], rank);
    gsenc_model *m = NULL;
    EXPECT(gsenc_model_read(path, &m), GSENC_STATUS_OK);
    if (m) {
        gsenc_model_info info;
        info.struct_size = sizeof info;
        EXPECT(gsenc_model_info_get(m, &info), GSENC_STATUS_OK);
        CHECK(info.rank == (uint32_t)rank && info.step == 2 && info.warm_started == 1 && info.count == 150, "model of rank %d: rank %u step %llu warm %d count %llu",
              rank, info.rank, (unsigned long long)info.step, info.warm_started, (unsigned long long)info.count);
        gsenc_model_destroy(m);
    }
    if (rank == 0) {
        snprintf(path, sizeof path, "%s/rho_000002.gsi", argv[1]);
        FILE *f = fopen(path, "r");
        CHECK(f != NULL, "rank 0 wrote the step index %s", path);
        if (f) fclose(f);
    }
    free(slab), free(pos), free(hh), free(val);

    int mine[2] = {passes, failures}, all[2] = {0, 0};
    MPI_Reduce(mine, all, 2, MPI_INT, MPI_SUM, 0, MPI_COMM_WORLD);
    if (rank == 0) printf("c-mpi (%d ranks): %d passed, %d failed\n", size, all[0], all[1]);
    MPI_Finalize();
    return failures == 0 ? 0 : 1;
}
