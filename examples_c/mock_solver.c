/* A mock simulation that uses gsenc the way a production code would.
 *
 * The "solver" advances a few moving, deforming blobs of a scalar (see
 * mock_field.h) and holds the field in three forms, as real codes do:
 *  - a 64^3 grid of doubles with one ghost layer on every side (the
 *    ghosts hold garbage; gsenc reads the interior through strides);
 *  - tracer particles stored as an array of structs (position, velocity,
 *    smoothing length, value), handed over in place through tuple strides;
 *  - AMR cells in float32, a 16^3 base level refined twice near the blobs.
 * At every output step it pushes all three forms as the fields "grid",
 * "tracers" and "amr"; gsenc's thread encodes them (each warm-started from
 * its previous step) and writes OUTPUT_DIR/FIELD_STEP.gsm. This mock then
 * waits (gsenc_wait) to print each step's PSNR; a production code would
 * push and go on (see benches/insitu.c). An OUTPUT_DIR ending in ".h5"
 * is an HDF5 store instead (gsenc built with HDF5): every model in one file.
 *
 * usage: mock_solver OUTPUT_DIR [STEPS [BUDGET [ITERATIONS [WARM_ITERATIONS [WARM]]]]]
 * (defaults 20 steps, 3000 Gaussians, the schedules' iterations, warm
 * starts "auto"; WARM is off, coarse, dense or auto). */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "gsenc.h"
#include "mock_field.h"

#define N 64                 /* interior cells per axis */
#define NG (N + 2)           /* with one ghost layer on each side */
#define TRACERS_PER_AXIS 32  /* 32^3 tracer particles */
#define BASE 16              /* AMR base level cells per axis */

typedef struct {
    double x[3];
    double v[3];
    double h; /* SPH smoothing length */
    double value;
} tracer;

typedef struct {
    float *centres, *edges, *values;
    size_t count, capacity;
} amr_cells;

static int check(gsenc_status s, const char *what) {
    if (s == GSENC_STATUS_OK) return 0;
    size_t n = gsenc_last_error(NULL, 0);
    char *msg = malloc(n + 1);
    if (msg) gsenc_last_error(msg, n + 1);
    fprintf(stderr, "mock_solver: %s failed: %s: %s\n", what, gsenc_status_string(s), msg ? msg : "?");
    free(msg);
    return 1;
}

static void fill_grid(double *g, double t) {
    for (size_t i = 0; i < (size_t)NG * NG * NG; i++) g[i] = 1e30; /* ghost garbage */
    for (int k = 0; k < N; k++)
        for (int j = 0; j < N; j++)
            for (int i = 0; i < N; i++) {
                double x[3] = {(i + 0.5) / N, (j + 0.5) / N, (k + 0.5) / N};
                g[((size_t)(k + 1) * NG + (j + 1)) * NG + (i + 1)] = mock_field(x, t);
            }
}

/* Tracers start on a jittered lattice and move with a periodic,
 * volume-preserving flow; each carries the field at its position. */
static void init_tracers(tracer *p, int n) {
    unsigned s = 12345u;
    for (int q = 0; q < n; q++) {
        int idx[3] = {q % TRACERS_PER_AXIS, q / TRACERS_PER_AXIS % TRACERS_PER_AXIS, q / (TRACERS_PER_AXIS * TRACERS_PER_AXIS)};
        for (int c = 0; c < 3; c++) {
            s = s * 1664525u + 1013904223u;
            p[q].x[c] = (idx[c] + 0.25 + 0.5 * (s >> 8) / 16777216.0) / TRACERS_PER_AXIS;
        }
        p[q].h = 1.3 / TRACERS_PER_AXIS;
    }
}

static void advance_tracers(tracer *p, int n, double t) {
    const double two_pi = 6.283185307179586;
    for (int q = 0; q < n; q++) {
        double *x = p[q].x;
        p[q].v[0] = 0.1 * sin(two_pi * x[1]);
        p[q].v[1] = 0.1 * sin(two_pi * x[2]);
        p[q].v[2] = 0.1 * sin(two_pi * x[0]);
        for (int c = 0; c < 3; c++) {
            x[c] = fmod(x[c] + MOCK_DT * p[q].v[c] + 1.0, 1.0);
        }
        p[q].value = mock_field(x, t);
    }
}

static int add_cell(amr_cells *c, const double centre[3], double edge, double t) {
    if (c->count == c->capacity) {
        size_t cap = c->capacity ? 2 * c->capacity : 4096;
        float *a = realloc(c->centres, cap * 3 * sizeof(float));
        if (a) c->centres = a;
        float *b = realloc(c->edges, cap * 3 * sizeof(float));
        if (b) c->edges = b;
        float *v = realloc(c->values, cap * sizeof(float));
        if (v) c->values = v;
        if (!a || !b || !v) return 1;
        c->capacity = cap;
    }
    for (int k = 0; k < 3; k++) {
        c->centres[3 * c->count + k] = (float)centre[k];
        c->edges[3 * c->count + k] = (float)edge;
    }
    c->values[c->count++] = (float)mock_field(centre, t);
    return 0;
}

/* Refines a cell into 8 children while it is near a blob: twice within
 * 1.2 widths of a centre, once within 2.5. */
static int refine(amr_cells *c, const double centre[3], double edge, int level, double t) {
    double d = mock_blob_distance(centre, t);
    if ((level == 0 && d < 2.5) || (level == 1 && d < 1.2)) {
        for (int o = 0; o < 8; o++) {
            double child[3];
            for (int k = 0; k < 3; k++) child[k] = centre[k] + ((o >> k & 1) ? 0.25 : -0.25) * edge;
            if (refine(c, child, edge / 2, level + 1, t)) return 1;
        }
        return 0;
    }
    return add_cell(c, centre, edge, t);
}

static int build_amr(amr_cells *c, double t) {
    c->count = 0;
    for (int k = 0; k < BASE; k++)
        for (int j = 0; j < BASE; j++)
            for (int i = 0; i < BASE; i++) {
                double centre[3] = {(i + 0.5) / BASE, (j + 0.5) / BASE, (k + 0.5) / BASE};
                if (refine(c, centre, 1.0 / BASE, 0, t)) return 1;
            }
    return 0;
}

int main(int argc, char **argv) {
    if (argc < 2) {
        fprintf(stderr, "usage: %s OUTPUT_DIR [STEPS [BUDGET [ITERATIONS [WARM_ITERATIONS [WARM]]]]]\n", argv[0]);
        return 2;
    }
    int steps = argc > 2 ? atoi(argv[2]) : 20;
    gsenc_config cfg = {.struct_size = sizeof cfg};
    if (check(gsenc_config_init(&cfg), "gsenc_config_init")) return 1;
    cfg.budget = argc > 3 ? strtoull(argv[3], NULL, 10) : 3000;
    cfg.iterations = argc > 4 ? (uint32_t)atoi(argv[4]) : 0;
    cfg.warm_iterations = argc > 5 ? (uint32_t)atoi(argv[5]) : 0;
    const char *warm = argc > 6 ? argv[6] : "auto";
    const char *names[] = {"off", "coarse", "dense", "auto"};
    const int32_t modes[] = {GSENC_WARM_OFF, GSENC_WARM_COARSE, GSENC_WARM_DENSE, GSENC_WARM_AUTO};
    cfg.warm_start = -1;
    for (int i = 0; i < 4; i++)
        if (strcmp(warm, names[i]) == 0) cfg.warm_start = modes[i];
    if (cfg.warm_start < 0) {
        fprintf(stderr, "mock_solver: unknown warm start '%s' (off, coarse, dense or auto)\n", warm);
        return 2;
    }
    cfg.fixed_range = 1; /* the solver knows its field's range */
    cfg.value_min = 0.0;
    cfg.value_max = 4.0;
    for (int k = 0; k < 3; k++) {
        cfg.dims[k] = N; /* particles and cells are deposited on 64^3 */
        cfg.bounds_min[k] = 0.0;
        cfg.bounds_max[k] = 1.0;
    }
    cfg.has_bounds = 1;
    cfg.output_dir = argv[1];
    size_t len = strlen(argv[1]);
    if (len > 3 && strcmp(argv[1] + len - 3, ".h5") == 0) cfg.output_format = GSENC_OUTPUT_HDF5;
    cfg.threads = 0; /* this mock waits for every step (to print its PSNR), so the encode may use every core */
    gsenc_encoder *enc = NULL;
    if (check(gsenc_encoder_create(&cfg, &enc), "gsenc_encoder_create")) return 1;

    double *grid = malloc(sizeof(double) * NG * NG * NG);
    int ntracers = TRACERS_PER_AXIS * TRACERS_PER_AXIS * TRACERS_PER_AXIS;
    tracer *tracers = calloc((size_t)ntracers, sizeof(tracer));
    amr_cells cells = {0};
    if (!grid || !tracers) return 1;
    init_tracers(tracers, ntracers);

    /* How gsenc sees the solver's memory: set once, the data change in place. */
    gsenc_grid g = {.struct_size = sizeof g};
    g.dtype = GSENC_DTYPE_FLOAT64;
    g.data = grid + ((size_t)1 * NG + 1) * NG + 1; /* interior cell (0, 0, 0) */
    for (int k = 0; k < 3; k++) g.extents[k] = N;
    g.strides[0] = 1;
    g.strides[1] = NG;
    g.strides[2] = (int64_t)NG * NG;
    g.spacing = 1.0 / N;
    const int64_t rec = sizeof(tracer) / sizeof(double); /* elements per tracer record */
    gsenc_particles p = {.struct_size = sizeof p};
    p.dtype = GSENC_DTYPE_FLOAT64;
    p.count = (uint64_t)ntracers;
    p.positions = tracers[0].x;
    p.position_stride = rec;
    p.position_component_stride = 1;
    p.smoothing_length = &tracers[0].h;
    p.smoothing_length_stride = rec;
    p.values = &tracers[0].value;
    p.value_stride = rec;

    int failed = 0;
    for (int step = 0; step < steps && !failed; step++) {
        double t = step * MOCK_DT * 4; /* an output every 4 solver steps */
        fill_grid(grid, t);
        for (int sub = 0; sub < 4; sub++) advance_tracers(tracers, ntracers, t - (3 - sub) * MOCK_DT);
        if (build_amr(&cells, t)) return 1;
        gsenc_cells c = {.struct_size = sizeof c};
        c.dtype = GSENC_DTYPE_FLOAT32;
        c.layout = GSENC_CELLS_BOXES;
        c.count = cells.count;
        c.centres = cells.centres;
        c.edges = cells.edges;
        c.values = cells.values;

        clock_t t0 = clock();
        failed |= check(gsenc_push_grid(enc, "grid", (uint64_t)step, t, &g), "gsenc_push_grid");
        failed |= check(gsenc_push_particles(enc, "tracers", (uint64_t)step, t, &p), "gsenc_push_particles");
        failed |= check(gsenc_push_cells(enc, "amr", (uint64_t)step, t, &c), "gsenc_push_cells");
        failed |= check(gsenc_wait(enc, NULL), "gsenc_wait");
        if (failed) break;
        const char *fields[3] = {"grid", "tracers", "amr"};
        printf("step %2d  t=%.2f  %zu cells ", step, t, cells.count);
        for (int f = 0; f < 3; f++) {
            uint64_t s;
            double psnr;
            failed |= check(gsenc_encoder_last_step(enc, fields[f], &s, &psnr), "gsenc_encoder_last_step");
            printf(" %s %.2f dB", fields[f], psnr);
        }
        printf("  (%.1f s CPU)\n", (double)(clock() - t0) / CLOCKS_PER_SEC);
        fflush(stdout);
    }
    gsenc_encoder_destroy(enc);
    free(grid);
    free(tracers);
    free(cells.centres);
    free(cells.edges);
    free(cells.values);
    return failed;
}
