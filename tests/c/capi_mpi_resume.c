/* A decomposed run restarted from a checkpoint, under mpirun -n 1, 2 and 4
 * (tests/mpi.sh): one run encodes a grid field and a particle field (the
 * particles drifting, so that the lattice of a later step's data is not
 * the first's) for steps 1 to 3; a second run resumes both from every
 * rank's step-1 model (gsenc_encoder_resume, collective) and pushes steps 2
 * and 3. Every rank's model and rank 0's step index of steps 2 and 3 must
 * be byte for byte the unbroken run's. So must those of runs restarted
 * from their own output (gsenc_encoder_resume_stored): a folder, and an
 * HDF5 store (OUTPUT_DIR/restarted.h5, which tests/mpi.sh compares).
 * Misuse is refused on every rank: one rank's NULL model, another rank's
 * model, a resume after a push, a step the output does not hold.
 * usage: capi_mpi_resume OUTPUT_DIR */
#include "gsenc.h"
#include "mpi_checks.h"
#include <math.h>
#include <mpi.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

static int size = 1;

#define N 24
#define SIDE 14

/* Pushes step `step` of both fields: this rank's slab of the grid, and its
 * particles (a lattice that drifts along x by 0.02 a step). */
static void push_step(gsenc_encoder *enc, int step) {
    int x0 = rank * N / size, x1 = (rank + 1) * N / size, nx = x1 - x0;
    float *slab = malloc(sizeof(float) * (size_t)nx * N * N);
    fill_slab(slab, N, x0, nx, step);
    gsenc_grid g = {sizeof g, GSENC_DTYPE_FLOAT32, slab, {(uint64_t)nx, N, N}, {0, 0, 0}, {(double)x0 / N, 0, 0}, 1.0 / N};
    EXPECT(gsenc_push_grid(enc, "rho", (uint64_t)step, step * 0.1, &g), GSENC_STATUS_OK);
    free(slab);
    double *pos = malloc(sizeof(double) * 3 * SIDE * SIDE * SIDE), *h = malloc(sizeof(double) * SIDE * SIDE * SIDE),
           *val = malloc(sizeof(double) * SIDE * SIDE * SIDE);
    gsenc_particles p = lattice_particles(SIDE, size, 0.02 * step, step, pos, h, val);
    EXPECT(gsenc_push_particles(enc, "tracer", (uint64_t)step, step * 0.1, &p), GSENC_STATUS_OK);
    free(pos), free(h), free(val);
}

/* The path of `field`'s step `step` model of rank `r` in `dir`. */
static void model_path(char *out, size_t len, const char *dir, const char *field, int step, int r) {
    if (r == 0)
        snprintf(out, len, "%s/%s_%06d.gsm", dir, field, step);
    else
        snprintf(out, len, "%s/%s_%06d_r%d.gsm", dir, field, step, r);
}

/* The whole file at `path` (its length in *len), or NULL. */
static unsigned char *slurp(const char *path, long *len) {
    FILE *f = fopen(path, "rb");
    if (!f) return NULL;
    fseek(f, 0, SEEK_END);
    *len = ftell(f);
    fseek(f, 0, SEEK_SET);
    unsigned char *b = malloc((size_t)*len + 1);
    size_t got = fread(b, 1, (size_t)*len, f);
    fclose(f);
    if ((long)got != *len) {
        free(b);
        return NULL;
    }
    return b;
}

static void same_file(const char *a, const char *b) {
    long la = 0, lb = 0;
    unsigned char *fa = slurp(a, &la), *fb = slurp(b, &lb);
    CHECK(fa && fb && la == lb && memcmp(fa, fb, (size_t)la) == 0, "%s and %s differ (%ld and %ld bytes)", a, b, la, lb);
    free(fa), free(fb);
}

/* This rank resumes `field` from rank `from`'s step-1 model of the unbroken run. */
static gsenc_status resume_from(gsenc_encoder *enc, const char *unbroken, const char *field, int from) {
    char path[1024];
    model_path(path, sizeof path, unbroken, field, 1, from);
    gsenc_model *m = NULL;
    EXPECT(gsenc_model_read(path, &m), GSENC_STATUS_OK);
    gsenc_status s = gsenc_encoder_resume(enc, m);
    gsenc_model_destroy(m);
    return s;
}

int main(int argc, char **argv) {
    if (argc < 2) {
        fprintf(stderr, "usage: capi_mpi_resume OUTPUT_DIR\n");
        return 2;
    }
    int provided = 0;
    MPI_Init_thread(&argc, &argv, MPI_THREAD_FUNNELED, &provided);
    MPI_Comm_rank(MPI_COMM_WORLD, &rank);
    MPI_Comm_size(MPI_COMM_WORLD, &size);
    char unbroken[900], restarted[900], stored[900], store[900];
    snprintf(unbroken, sizeof unbroken, "%s/unbroken", argv[1]);
    snprintf(restarted, sizeof restarted, "%s/restarted", argv[1]);
    snprintf(stored, sizeof stored, "%s/stored", argv[1]);
    snprintf(store, sizeof store, "%s/restarted.h5", argv[1]);
    if (rank == 0) {
        CHECK(mkdir(unbroken, 0755) == 0 && mkdir(restarted, 0755) == 0 && mkdir(stored, 0755) == 0, "make the output folders in %s", argv[1]);
    }
    MPI_Barrier(MPI_COMM_WORLD);

    gsenc_config cfg;
    cfg.struct_size = sizeof cfg;
    gsenc_config_init(&cfg);
    cfg.budget = 120;
    cfg.iterations = 60;
    cfg.warm_iterations = 30;
    cfg.dims[0] = cfg.dims[1] = cfg.dims[2] = N;
    cfg.halo = 3;
    cfg.output_dir = unbroken;

    gsenc_encoder *enc = NULL;
    EXPECT(gsenc_encoder_create_mpi(&cfg, MPI_Comm_c2f(MPI_COMM_WORLD), &enc), GSENC_STATUS_OK);
    for (int step = 1; step <= 3; step++) push_step(enc, step);
    EXPECT(gsenc_wait(enc, NULL), GSENC_STATUS_OK);
    /* A resume after a push: refused on every rank, the series unchanged. */
    EXPECT(resume_from(enc, unbroken, "rho", rank), GSENC_STATUS_INVALID_ARGUMENT);
    CHECK(strstr(last_error(), "has begun on this encoder already") != NULL, "resume after a push: %s", last_error());
    gsenc_encoder_destroy(enc);

    /* The restart: both fields resumed from step 1, steps 2 and 3 pushed. */
    cfg.output_dir = restarted;
    EXPECT(gsenc_encoder_create_mpi(&cfg, MPI_Comm_c2f(MPI_COMM_WORLD), &enc), GSENC_STATUS_OK);
    if (size > 1) {
        /* One rank without its model: it hears its own error, the others of it. */
        gsenc_status s = rank == size - 1 ? gsenc_encoder_resume(enc, NULL) : resume_from(enc, unbroken, "rho", rank);
        if (rank == size - 1)
            CHECK(s == GSENC_STATUS_NULL_POINTER, "the rank without a model got %s: %s", gsenc_status_string(s), last_error());
        else
            CHECK(s == GSENC_STATUS_MPI && strstr(last_error(), "failed to resume") != NULL, "the others got %s: %s", gsenc_status_string(s), last_error());
        /* Each rank with another rank's model: refused everywhere. */
        EXPECT(resume_from(enc, unbroken, "rho", (rank + 1) % size), GSENC_STATUS_INVALID_ARGUMENT);
        CHECK(strstr(last_error(), "piece; this is rank") != NULL, "another rank's model: %s", last_error());
    }
    EXPECT(resume_from(enc, unbroken, "rho", rank), GSENC_STATUS_OK);
    EXPECT(resume_from(enc, unbroken, "tracer", rank), GSENC_STATUS_OK);
    EXPECT(resume_from(enc, unbroken, "rho", rank), GSENC_STATUS_INVALID_ARGUMENT);
    for (int step = 2; step <= 3; step++) push_step(enc, step);
    EXPECT(gsenc_wait(enc, NULL), GSENC_STATUS_OK);
    gsenc_encoder_destroy(enc);

    /* A restart from the run's own output (gsenc_encoder_resume_stored):
     * a folder, where each rank reads its file, and an HDF5 store, which
     * rank 0 reads for every rank (tests/mpi.sh compares its steps 2 and 3
     * with the unbroken run's). The stopped run wrote steps 1 and 2 there,
     * and the restart goes on from step 1, as from a checkpoint taken
     * before the run stopped: it stores step 2 again, the same models. */
    for (int h5 = 0; h5 < 2; h5++) {
        gsenc_config out = cfg;
        out.output_dir = h5 ? store : stored;
        out.output_format = h5 ? GSENC_OUTPUT_HDF5 : GSENC_OUTPUT_FOLDER;
        EXPECT(gsenc_encoder_create_mpi(&out, MPI_Comm_c2f(MPI_COMM_WORLD), &enc), GSENC_STATUS_OK);
        for (int step = 1; step <= 2; step++) push_step(enc, step);
        EXPECT(gsenc_wait(enc, NULL), GSENC_STATUS_OK);
        gsenc_encoder_destroy(enc);
        EXPECT(gsenc_encoder_create_mpi(&out, MPI_Comm_c2f(MPI_COMM_WORLD), &enc), GSENC_STATUS_OK);
        /* A step the output does not hold: every rank hears of it. */
        gsenc_status s = gsenc_encoder_resume_stored(enc, "rho", 9);
        if (h5)
            CHECK(s == GSENC_STATUS_INVALID_ARGUMENT && strstr(last_error(), "holds no model /rho/9/rank_") != NULL, "a step the store lacks: %s: %s", gsenc_status_string(s), last_error());
        else
            CHECK(s == GSENC_STATUS_IO && strstr(last_error(), "rho_000009") != NULL, "a step the folder lacks: %s: %s", gsenc_status_string(s), last_error());
        EXPECT(gsenc_encoder_resume_stored(enc, "rho", 1), GSENC_STATUS_OK);
        EXPECT(gsenc_encoder_resume_stored(enc, "tracer", 1), GSENC_STATUS_OK);
        for (int step = 2; step <= 3; step++) push_step(enc, step);
        EXPECT(gsenc_wait(enc, NULL), GSENC_STATUS_OK);
        gsenc_encoder_destroy(enc);
    }

    const char *fields[2] = {"rho", "tracer"}, *again[2] = {restarted, stored};
    for (int d = 0; d < 2; d++)
        for (int f = 0; f < 2; f++)
            for (int step = 2; step <= 3; step++) {
                char a[1024], b[1024];
                model_path(a, sizeof a, unbroken, fields[f], step, rank);
                model_path(b, sizeof b, again[d], fields[f], step, rank);
                same_file(a, b);
                if (rank == 0) {
                    snprintf(a, sizeof a, "%s/%s_%06d.gsi", unbroken, fields[f], step);
                    snprintf(b, sizeof b, "%s/%s_%06d.gsi", again[d], fields[f], step);
                    same_file(a, b);
                }
            }

    int mine[2] = {passes, failures}, all[2] = {0, 0};
    MPI_Reduce(mine, all, 2, MPI_INT, MPI_SUM, 0, MPI_COMM_WORLD);
    if (rank == 0) printf("c-mpi-resume (%d ranks): %d passed, %d failed\n", size, all[0], all[1]);
    MPI_Finalize();
    return failures == 0 ? 0 : 1;
}
