/* Seeded random walks over the MPI side of the C API, run under mpirun -n
 * 2 and 4 (tests/mpi.sh), as a domain-decomposed simulation would call it
 * on a bad day: every rank makes the same calls in the same order (the
 * collectives match, as the header requires), but now and then one rank's
 * push is wrong in its own way (NaN or infinite values, NULL arrays, no
 * cells or particles, a grid off the lattice or of another spacing, a bad
 * dtype, struct size or field name, another step or form than the other
 * ranks', too little memory for its copy) or its encoder's outputs differ
 * from the others'. Encoders draw their budget, iterations, lattice, halo,
 * payload, warm start, value range and output (none, a folder, an HDF5
 * store when gsenc was built with one); calls are pushes of grids,
 * particles and cells, waits, polls, cancels and a destroy with a new
 * encoder.
 *
 * What every call must do, on every rank:
 * - return, within two minutes (else the walk aborts naming its seed: a
 *   rank waiting in a collective the others left);
 * - never GSENC_STATUS_INTERNAL, and a failure leaves a message;
 * - a collective call (create, every push) succeeds on every rank or on
 *   none, and a rank whose own push was wrong is among the failed;
 * - a push no rank spoiled succeeds, whatever failed before it: a refused
 *   step leaves every rank's encoder able to go on; a rank may push no
 *   particles or cells but at a field's first step (a grid slab of no
 *   cells, or no items at the first step, may be refused, on every rank);
 * - after the walk's last wait, every step whose push succeeded is there
 *   in the folder, each rank's model reading back as that rank's model of
 *   that field and step, decoding to finite values (tests/mpi.sh decodes
 *   each step index and verifies each store with the tool).
 *
 * Usage: capi_mpi_walk OUTPUT_DIR [WALKS [FIRST_SEED]] (default 12 walks
 * from seed 1); GSENC_MPI_WALK_TRACE=1 prints every rank's calls and the
 * faults it drew. */
#define _POSIX_C_SOURCE 200809L /* setenv, alarm */
#include "gsenc.h"
#include <math.h>
#include <mpi.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#define CALLS 24
#define MAX_PUSHED 256
#define WATCHDOG_S 120

static int rank = 0, size = 1, trace = 0;
static uint64_t walk_seed = 0;
static char last_call[256];
/* What the walks did: pushes and creates taken and refused, models read back. */
static long pushes_ok = 0, pushes_refused = 0, creates_ok = 0, creates_refused = 0, models_read = 0;

/* splitmix64: `shared` draws the same on every rank, `own` this rank's. */
static uint64_t next(uint64_t *s) {
    uint64_t z = (*s += 0x9e3779b97f4a7c15ull);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    return z ^ (z >> 31);
}
static uint64_t shared, own;
static int below(uint64_t *s, int n) { return (int)(next(s) % (uint64_t)n); }
static int chance(uint64_t *s, int percent) { return below(s, 100) < percent; }

static const char *last_error(void) {
    static char buf[1024];
    gsenc_last_error(buf, sizeof buf);
    return buf;
}

static void fail(const char *what) {
    fprintf(stderr, "capi_mpi_walk: at %s: %s\n", last_call, what);
    MPI_Abort(MPI_COMM_WORLD, 1);
}

static void on_alarm(int sig) {
    (void)sig;
    static const char msg[] = "capi_mpi_walk: a call has not returned in two minutes (a rank waiting in a collective?): ";
    ssize_t w = write(2, msg, sizeof msg - 1);
    w = write(2, last_call, strlen(last_call));
    w = write(2, "\n", 1);
    (void)w;
    _exit(3);
}

/* Starts a call: its name, rank and walk seed for failures and the trace
 * (kept whole for the watchdog, which may only write it), and the
 * watchdog. */
static void call(const char *fmt, const char *a, long long b) {
    int n = snprintf(last_call, sizeof last_call, "rank %d, walk seed %llu: ", rank, (unsigned long long)walk_seed);
    snprintf(last_call + n, sizeof last_call - (size_t)n, fmt, a, b);
    if (trace) fprintf(stderr, "  %s\n", last_call);
    alarm(WATCHDOG_S);
}

/* What every answer must be: a named status, a message when it failed. */
static void sound(gsenc_status s) {
    char why[1200];
    if (s == GSENC_STATUS_INTERNAL) {
        snprintf(why, sizeof why, "GSENC_STATUS_INTERNAL: %s", last_error());
        fail(why);
    }
    if (s != GSENC_STATUS_OK && last_error()[0] == '\0') fail("a failure without a message");
    if (s > GSENC_STATUS_DEVICE) fail("a status the header does not name");
}

/* A collective call's answers: all ranks succeeded (1), none did (0), or
 * the walk fails. `must_fail`: this rank spoiled it for sure, so it must
 * fail; `spoiled`: this rank changed something; `anyone_spoiled` is then
 * whether any rank did. */
static int together(gsenc_status s, int must_fail, int spoiled, int *anyone_spoiled) {
    sound(s);
    int ok = s == GSENC_STATUS_OK, lo = 0, hi = 0, any = 0;
    MPI_Allreduce(&ok, &lo, 1, MPI_INT, MPI_MIN, MPI_COMM_WORLD);
    MPI_Allreduce(&ok, &hi, 1, MPI_INT, MPI_MAX, MPI_COMM_WORLD);
    MPI_Allreduce(&spoiled, &any, 1, MPI_INT, MPI_MAX, MPI_COMM_WORLD);
    char why[1400];
    if (lo != hi) {
        snprintf(why, sizeof why, "a collective call succeeded on some ranks and not on others (here %s%s%s)", gsenc_status_string(s), ok ? "" : ": ", ok ? "" : last_error());
        fail(why);
    }
    if (must_fail && ok) fail("this rank's spoiled call succeeded");
    if (anyone_spoiled) *anyone_spoiled = any;
    return ok;
}

/* The field in the unit box: positive (log10 takes it), smooth, drifting. */
static double value_at(double x, double y, double z, uint64_t step) {
    double dx = x - 0.3 - 0.02 * (double)(step % 16), dy = y - 0.5, dz = z - 0.6;
    return 0.2 + exp(-(dx * dx + dy * dy + dz * dz) / 0.03);
}

typedef struct {
    char name[16];
    int form;        /* 0 grid, 1 particles, 2 cells */
    int n;           /* cells of a grid, or of the lattice particles and cells sit on, along each axis */
    int hexahedra;   /* cells: as hexahedra, not boxes (a layout is part of the form) */
    uint64_t step;   /* the last step pushed, */
    int started;     /* if any */
} field_t;

typedef struct {
    char field[16];
    uint64_t step;
} pushed_t;

typedef struct {
    gsenc_encoder *enc;
    char dir[512];   /* the folder models go to, or "" */
    int store;       /* models go to an HDF5 store */
    field_t fields[4];
    pushed_t ok[MAX_PUSHED];
    int oks;
} walk_t;

/* Buffers of one push, big enough for any draw. */
#define MAX_ITEMS 4096
static double dbuf[3][3 * MAX_ITEMS], corners[3 * 8 * MAX_ITEMS];
static float fbuf[MAX_ITEMS * 4];
static int64_t conn[8 * MAX_ITEMS];

/* This rank's share of x: [x0, x1) of the unit box. */
static double x_lo(void) { return (double)rank / size; }
static double x_hi(void) { return (double)(rank + 1) / size; }

/* Spoils one thing of this rank's push (drawn from `own`), or nothing:
 * returns the fault's number (0: none). Grid, particles and cells share
 * the numbering of what they have in common. */
static int draw_fault(int percent) { return chance(&own, percent) ? 1 + below(&own, 9) : 0; }

/* Set by a push: its fault is one no push may be taken with. A NULL array
 * or an odd stride where there is nothing to read, and a grid off the
 * lattice or of another spacing at a field's first step (no lattice yet),
 * may be taken or refused, but alike on every rank; another step than the
 * others' is checked in `push` (every rank may have drawn it). */
static int sure;
/* Set by a push: this rank has no cells of the grid, no particles or no
 * cells. A grid slab of none is refused; particles and cells may be none
 * on a rank but at a field's first step. */
static int empty;

static gsenc_status push_grid(walk_t *w, field_t *f, uint64_t step, int fault) {
    int n = f->n, i0 = rank * n / size, i1 = (rank + 1) * n / size, nx = i1 - i0;
    double h = 1.0 / n;
    for (int k = 0; k < n; k++)
        for (int j = 0; j < n; j++)
            for (int i = 0; i < nx; i++)
                fbuf[i + nx * (j + n * k)] = (float)value_at((i0 + i + 0.5) * h, (j + 0.5) * h, (k + 0.5) * h, step);
    gsenc_grid g = {sizeof g, GSENC_DTYPE_FLOAT32, fbuf, {(uint64_t)nx, (uint64_t)n, (uint64_t)n}, {0, 0, 0}, {i0 * h, 0, 0}, h};
    const char *name = f->name;
    switch (fault) {
    case 1: fbuf[below(&own, nx * n * n > 0 ? nx * n * n : 1)] = NAN; break;
    case 2: fbuf[0] = INFINITY; break;
    case 3: g.data = NULL; break;
    case 4: g.origin[1] += 0.5 * h; break;       /* off the lattice */
    case 5: g.spacing = h * 1.5; break;          /* another spacing */
    case 6: g.dtype = 77; break;
    case 7: g.struct_size = 3; break;
    case 8: name = chance(&own, 50) ? "a/b" : NULL; break;
    case 9: step += 1; break;                    /* another step than the others' */
    }
    if (fault == 1 && nx == 0) fbuf[0] = NAN, g.extents[0] = 1; /* a slab of none has no value to spoil */
    sure = (fault >= 1 && fault <= 3 && (nx > 0 || fault == 1)) || (fault >= 4 && fault <= 5 && f->started) || (fault >= 6 && fault <= 8);
    empty = nx == 0;
    return gsenc_push_grid(w->enc, name, step, 0.01 * (double)step, &g);
}

/* Particles on a lattice of side^3 in this rank's x range (or none). */
static int make_particles(int side, uint64_t step) {
    int np = 0;
    for (int k = 0; k < side; k++)
        for (int j = 0; j < side; j++)
            for (int i = 0; i < side; i++) {
                double x = (i + 0.5) / side, y = (j + 0.5) / side, z = (k + 0.5) / side;
                if (x < x_lo() || x >= x_hi() || np >= MAX_ITEMS) continue;
                dbuf[0][3 * np] = x, dbuf[0][3 * np + 1] = y, dbuf[0][3 * np + 2] = z;
                dbuf[1][np] = 1.3 / side;
                dbuf[2][np] = value_at(x, y, z, step);
                np++;
            }
    return np;
}

static gsenc_status push_particles(walk_t *w, field_t *f, uint64_t step, int fault) {
    int np = make_particles(f->n, step);
    gsenc_particles p;
    memset(&p, 0, sizeof p);
    p.struct_size = sizeof p, p.dtype = GSENC_DTYPE_FLOAT64, p.count = (uint64_t)np;
    p.positions = dbuf[0], p.smoothing_length = dbuf[1], p.values = dbuf[2];
    const char *name = f->name;
    int spoil = np > 0 ? below(&own, np) : 0;
    switch (fault) {
    case 1: dbuf[2][spoil] = NAN; break;
    case 2: dbuf[0][3 * spoil + 1] = INFINITY; break;
    case 3: p.values = NULL; break;
    case 4: dbuf[1][spoil] = -1.0; break;
    case 5: p.position_stride = INT64_MAX / 2; break;
    case 6: p.dtype = 77; break;
    case 7: p.struct_size = 3; break;
    case 8: name = chance(&own, 50) ? "a/b" : NULL; break;
    case 9: step += 1; break;
    }
    if (np == 0 && (fault == 1 || fault == 2 || fault == 4)) p.count = 1, p.values = NULL; /* none to spoil: spoil the call */
    sure = fault != 0 && fault < 9 && (np > 0 || (fault != 3 && fault != 5));
    empty = np == 0;
    return gsenc_push_particles(w->enc, name, step, 0.01 * (double)step, &p);
}

static gsenc_status push_cells(walk_t *w, field_t *f, uint64_t step, int fault) {
    int nc = make_particles(f->n, step); /* cell centres on the same lattice */
    int hexahedra = f->hexahedra;
    gsenc_cells c;
    memset(&c, 0, sizeof c);
    c.struct_size = sizeof c, c.dtype = GSENC_DTYPE_FLOAT64, c.count = (uint64_t)nc, c.values = dbuf[2];
    double e = 1.0 / f->n;
    if (hexahedra) {
        /* Each cell its own eight corners, in VTK order. */
        c.layout = GSENC_CELLS_HEXAHEDRA, c.points = corners, c.point_count = (uint64_t)nc * 8, c.connectivity = conn;
        for (int q = 0; q < nc; q++)
            for (int v = 0; v < 8; v++) {
                double dx = (v == 1 || v == 2 || v == 5 || v == 6) ? 0.5 : -0.5, dy = (v == 2 || v == 3 || v == 6 || v == 7) ? 0.5 : -0.5, dz = v >= 4 ? 0.5 : -0.5;
                double *pt = &corners[3 * (8 * q + v)];
                pt[0] = dbuf[0][3 * q] + dx * e, pt[1] = dbuf[0][3 * q + 1] + dy * e, pt[2] = dbuf[0][3 * q + 2] + dz * e;
                conn[8 * q + v] = 8 * q + v;
            }
    } else {
        c.layout = GSENC_CELLS_BOXES, c.centres = dbuf[0], c.edges = dbuf[1];
        for (int q = 0; q < nc; q++) dbuf[1][3 * q] = dbuf[1][3 * q + 1] = dbuf[1][3 * q + 2] = e;
    }
    const char *name = f->name;
    int spoil = nc > 0 ? below(&own, nc) : 0;
    switch (fault) {
    case 1: dbuf[2][spoil] = NAN; break;
    case 2:
        if (c.layout == GSENC_CELLS_HEXAHEDRA && nc > 0) corners[3 * 8 * spoil + 2] = -INFINITY;
        else dbuf[0][3 * spoil] = -INFINITY;
        break;
    case 3:
        if (c.layout == GSENC_CELLS_HEXAHEDRA) c.points = NULL;
        else c.centres = NULL;
        break;
    case 4:
        if (c.layout == GSENC_CELLS_HEXAHEDRA && nc > 0) /* a cell of no volume: its corners at one point */
            for (int v = 1; v < 8; v++) memcpy(&corners[3 * (8 * spoil + v)], &corners[3 * (8 * spoil)], 3 * sizeof(double));
        else
            dbuf[1][3 * spoil + 2] = -e;
        break;
    case 5: c.layout = 9; break;
    case 6: c.dtype = 77; break;
    case 7: c.struct_size = 3; break;
    case 8: name = chance(&own, 50) ? "a/b" : NULL; break;
    case 9: step += 1; break;
    }
    if (nc == 0 && (fault == 1 || fault == 2 || fault == 4)) c.count = 1, c.values = NULL;
    sure = fault != 0 && fault < 9 && (nc > 0 || fault != 3);
    empty = nc == 0;
    return gsenc_push_cells(w->enc, name, step, 0.01 * (double)step, &c);
}

/* A new encoder for the walk (collective), its outputs under `base`. */
static int create(walk_t *w, const char *base, int k) {
    gsenc_config cfg;
    cfg.struct_size = sizeof cfg;
    gsenc_config_init(&cfg);
    cfg.budget = 8 + (uint64_t)below(&shared, 40);
    cfg.iterations = 10 + (uint32_t)below(&shared, 30);
    cfg.warm_iterations = 5 + (uint32_t)below(&shared, 15);
    cfg.points = 256 + (uint32_t)below(&shared, 768);
    cfg.schedule = below(&shared, 5);
    cfg.warm_start = below(&shared, 4);
    cfg.payload = below(&shared, 4);
    cfg.halo = (uint32_t)below(&shared, 5);
    for (int a = 0; a < 3; a++) cfg.dims[a] = 6 + (uint32_t)below(&shared, 12);
    if (chance(&shared, 20)) cfg.transform = GSENC_TRANSFORM_LOG10;
    if (chance(&shared, 20)) cfg.fixed_range = 1, cfg.value_min = cfg.transform ? -1.0 : 0.0, cfg.value_max = cfg.transform ? 0.2 : 1.5;
    if (chance(&shared, 20)) {
        cfg.has_bounds = 1;
        for (int a = 0; a < 3; a++) cfg.bounds_min[a] = -0.25, cfg.bounds_max[a] = 1.25;
    }
    cfg.seed_init = next(&shared) % 1000;
    w->store = 0, w->dir[0] = '\0';
    int output = below(&shared, 10); /* 0-5 a folder, 6-7 none, 8-9 a store */
#ifndef GSENC_WALK_HDF5
    if (output >= 8) output = 0;
#endif
    if (output <= 5) {
        snprintf(w->dir, sizeof w->dir, "%s/e%d", base, k);
        if (rank == 0) mkdir(w->dir, 0755);
        MPI_Barrier(MPI_COMM_WORLD);
        cfg.output_dir = w->dir;
    } else if (output >= 8) {
        snprintf(w->dir, sizeof w->dir, "%s/e%d.h5", base, k);
        cfg.output_dir = w->dir, cfg.output_format = GSENC_OUTPUT_HDF5, w->store = 1;
    }
    /* Now and then one rank is configured apart: no outputs where the
     * others have some, or a zero budget. */
    int wrong = 0;
    if (chance(&own, 4)) {
        if (cfg.output_dir != NULL && chance(&own, 50)) cfg.output_dir = NULL, wrong = 1;
        else cfg.budget = 0, wrong = 1;
    }
    w->enc = NULL;
    call("create (output %s), encoder %lld", w->dir[0] ? w->dir : "none", k);
    gsenc_status s = gsenc_encoder_create_mpi(&cfg, MPI_Comm_c2f(MPI_COMM_WORLD), &w->enc);
    int ok = together(s, wrong, wrong, NULL);
    if (!ok && w->enc != NULL) fail("a failed create gave a handle");
    *(ok ? &creates_ok : &creates_refused) += 1;
    if (!ok) w->dir[0] = '\0', w->store = 0;
    /* The fields: two grids, particles, cells, each its own lattice. */
    for (int i = 0; i < 4; i++) {
        field_t *f = &w->fields[i];
        f->form = i < 2 ? 0 : i - 1;
        snprintf(f->name, sizeof f->name, "%s%d", f->form == 0 ? "g" : f->form == 1 ? "p" : "c", i);
        f->n = f->form == 0 ? 2 + below(&shared, 14) : 3 + below(&shared, 12);
        f->hexahedra = chance(&shared, 30);
        f->step = 0, f->started = 0;
    }
    w->oks = 0;
    return ok;
}

/* One push of a drawn field: mostly the next step, all ranks alike. */
static void push(walk_t *w) {
    field_t *f = &w->fields[below(&shared, 4)];
    uint64_t step = f->started + f->step + (uint64_t)below(&shared, 3);
    int shared_wrong = 0, form = f->form;
    if (chance(&shared, 5)) step = f->step, shared_wrong = f->started;  /* a step again, on every rank */
    if (chance(&shared, 4)) form = (form + 1) % 3, shared_wrong = shared_wrong || f->started; /* another form, on every rank */
    int fault = draw_fault(12);
    if (fault == 0 && chance(&own, 3)) {
        /* Too little memory for this rank's copy. */
        fault = 10;
        setenv("GSENC_MEMORY_LIMIT", "1K", 1);
    }
    call(form == 0 ? "push grid %s step %lld" : form == 1 ? "push particles %s step %lld" : "push cells %s step %lld", f->name, (long long)step);
    gsenc_status s = form == 0 ? push_grid(w, f, step, fault) : form == 1 ? push_particles(w, f, step, fault) : push_cells(w, f, step, fault);
    if (fault == 10) unsetenv("GSENC_MEMORY_LIMIT");
    if (trace && (fault || empty)) fprintf(stderr, "  %s: fault %d%s: %s\n", last_call, fault, empty ? ", no items" : "", gsenc_status_string(s));
    int anyone_spoiled = 0, refusable = empty && (form == 0 || !f->started);
    int ok = together(s, sure, fault != 0 || refusable, &anyone_spoiled);
    int moved = fault == 9, some_moved = 0, all_moved = 0;
    MPI_Allreduce(&moved, &some_moved, 1, MPI_INT, MPI_MAX, MPI_COMM_WORLD);
    MPI_Allreduce(&moved, &all_moved, 1, MPI_INT, MPI_MIN, MPI_COMM_WORLD);
    if (ok && some_moved && !all_moved) fail("ranks pushing different steps were taken");
    step += (uint64_t)all_moved; /* every rank pushed the step after: that one was taken */
    int spoiled = anyone_spoiled || shared_wrong;
    if (!ok && !spoiled) {
        char why[1400];
        snprintf(why, sizeof why, "a push no rank spoiled failed: %s: %s", gsenc_status_string(s), last_error());
        fail(why);
    }
    *(ok ? &pushes_ok : &pushes_refused) += 1;
    if (ok) {
        f->step = step, f->started = 1;
        f->form = form; /* a field's first push sets its form */
        if (w->oks < MAX_PUSHED) {
            snprintf(w->ok[w->oks].field, sizeof w->ok[w->oks].field, "%s", f->name);
            w->ok[w->oks++].step = step;
        }
    }
}

/* Every step the walk pushed successfully, read back from the folder. */
static void check_folder(walk_t *w) {
    for (int i = 0; i < w->oks; i++) {
        char path[700];
        if (rank == 0) snprintf(path, sizeof path, "%s/%s_%06llu.gsm", w->dir, w->ok[i].field, (unsigned long long)w->ok[i].step);
        else snprintf(path, sizeof path, "%s/%s_%06llu_r%d.gsm", w->dir, w->ok[i].field, (unsigned long long)w->ok[i].step, rank);
        call("read %s", path, 0);
        gsenc_model *m = NULL;
        gsenc_status s = gsenc_model_read(path, &m);
        sound(s);
        if (s != GSENC_STATUS_OK) {
            char why[1400];
            snprintf(why, sizeof why, "a step pushed and waited for is not in the folder: %s", last_error());
            fail(why);
        }
        gsenc_model_info info;
        info.struct_size = sizeof info;
        char field[32];
        size_t length = 0;
        if (gsenc_model_info_get(m, &info) != GSENC_STATUS_OK || gsenc_model_field(m, field, sizeof field, &length) != GSENC_STATUS_OK) fail(last_error());
        if (info.step != w->ok[i].step || info.rank != (uint32_t)rank || strcmp(field, w->ok[i].field) != 0) fail("the model read back is not this rank's model of that field and step");
        uint64_t dims[3] = {5, 4, 3};
        float out[60];
        sound(s = gsenc_model_decode(m, dims, out, 60));
        if (s != GSENC_STATUS_OK) fail(last_error());
        for (int v = 0; v < 60; v++)
            if (!isfinite(out[v])) fail("a decoded value is not finite");
        gsenc_model_destroy(m);
        models_read++;
    }
}

static void walk(const char *base, uint64_t seed) {
    walk_seed = seed;
    shared = seed * 0x2545f4914f6cdd1dull;
    own = shared ^ (0x9e3779b97f4a7c15ull * (uint64_t)(rank + 1));
    char dir[600];
    snprintf(dir, sizeof dir, "%s/w%llu", base, (unsigned long long)seed);
    if (rank == 0) mkdir(dir, 0755);
    MPI_Barrier(MPI_COMM_WORLD);
    walk_t w;
    memset(&w, 0, sizeof w);
    int encoders = 0;
    create(&w, dir, encoders++);
    for (int c = 0; c < CALLS; c++) {
        if (w.enc == NULL) {
            create(&w, dir, encoders++);
            continue;
        }
        int what = below(&shared, 20);
        if (what < 14) {
            push(&w);
        } else if (what < 16) {
            call("wait%s", "", 0);
            gsenc_status s = gsenc_wait(w.enc, NULL);
            sound(s);
            /* A step failed in its encode: which ones are there, the walk
             * does not know (the message names the first alone). */
            if (s != GSENC_STATUS_OK) w.oks = 0;
        } else if (what < 18) {
            if (w.oks == 0) continue;
            pushed_t *p = &w.ok[below(&own, w.oks)];
            gsenc_job job;
            memset(&job, 0xA5, sizeof job); /* garbage: poll must fill it */
            job.struct_size = sizeof job;
            call("poll %s step %lld", p->field, (long long)p->step);
            gsenc_status s = gsenc_poll(w.enc, p->field, p->step, &job);
            sound(s);
            if (s == GSENC_STATUS_OK && (job.state < GSENC_JOB_QUEUED || job.state > GSENC_JOB_CANCELLED)) fail("poll gave an unknown state");
        } else if (what < 19) {
            call("cancel%s", "", 0);
            gsenc_status s = gsenc_encoder_cancel(w.enc);
            sound(s);
            if (s != GSENC_STATUS_OK) fail(last_error());
            /* Cancelled steps are not written: what is there is not known. */
            w.oks = 0;
        } else {
            call("destroy%s", "", 0);
            gsenc_status s = gsenc_wait(w.enc, NULL);
            sound(s);
            int fine = s == GSENC_STATUS_OK;
            gsenc_encoder_destroy(w.enc);
            if (fine && !w.store && w.dir[0]) check_folder(&w);
            w.enc = NULL;
        }
    }
    if (w.enc != NULL) {
        call("last wait%s", "", 0);
        gsenc_status s = gsenc_wait(w.enc, NULL);
        sound(s);
        int fine = s == GSENC_STATUS_OK;
        call("last destroy%s", "", 0);
        gsenc_encoder_destroy(w.enc);
        if (fine && !w.store && w.dir[0]) check_folder(&w);
    }
    alarm(0);
}

int main(int argc, char **argv) {
    if (argc < 2) {
        fprintf(stderr, "usage: capi_mpi_walk OUTPUT_DIR [WALKS [FIRST_SEED]]\n");
        return 2;
    }
    int walks = argc > 2 ? atoi(argv[2]) : 12;
    uint64_t first = argc > 3 ? strtoull(argv[3], NULL, 10) : 1;
    trace = getenv("GSENC_MPI_WALK_TRACE") != NULL;
    int provided = 0;
    MPI_Init_thread(&argc, &argv, MPI_THREAD_FUNNELED, &provided);
    MPI_Comm_rank(MPI_COMM_WORLD, &rank);
    MPI_Comm_size(MPI_COMM_WORLD, &size);
    signal(SIGALRM, on_alarm);
    for (int i = 0; i < walks; i++) walk(argv[1], first + (uint64_t)i);
    MPI_Barrier(MPI_COMM_WORLD);
    long read = 0;
    MPI_Reduce(&models_read, &read, 1, MPI_LONG, MPI_SUM, 0, MPI_COMM_WORLD);
    if (rank == 0)
        printf("capi_mpi_walk: %d walks of %d calls from seed %llu on %d ranks: every answer sound (creates %ld taken, %ld refused; pushes %ld taken, %ld refused; %ld models read back)\n",
               walks, CALLS, (unsigned long long)first, size, creates_ok, creates_refused, pushes_ok, pushes_refused, read);
    MPI_Finalize();
    return 0;
}
