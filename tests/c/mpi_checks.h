/* What the MPI tests of the C API share (tests/c/capi_mpi.c,
 * capi_mpi_resume.c): their checks, counted per rank, and the field they
 * push: a blob drifting with the step, as a grid slab or as particles on a
 * lattice, each rank its own part. */
#ifndef GSENC_TESTS_MPI_CHECKS_H
#define GSENC_TESTS_MPI_CHECKS_H
#include "gsenc.h"
#include <math.h>
#include <stdio.h>
#include <string.h>

static int failures = 0, passes = 0, rank = 0;
#define CHECK(cond, ...) do { if (cond) { passes++; } else { failures++; fprintf(stderr, "rank %d FAIL line %d: ", rank, __LINE__); fprintf(stderr, __VA_ARGS__); fputc('\n', stderr); } } while (0)
#define EXPECT(call, status) do { gsenc_status s_ = (call); CHECK(s_ == (status), "%s gave %s, expected %s: %s", #call, gsenc_status_string(s_), gsenc_status_string(status), last_error()); } while (0)

static const char *last_error(void) {
    static char buf[1024];
    gsenc_last_error(buf, sizeof buf);
    return buf;
}

static float blob(double x, double y, double z, int step) {
    double dx = x - 0.4 - 0.05 * step, dy = y - 0.5, dz = z - 0.5;
    return (float)exp(-(dx * dx + dy * dy + dz * dz) / 0.02);
}

/* The blob at `step` on cells x0 .. x0 + nx of an n^3 grid of the unit box
 * (a rank's slab), x fastest. */
static void fill_slab(float *slab, int n, int x0, int nx, int step) {
    for (int k = 0; k < n; k++)
        for (int j = 0; j < n; j++)
            for (int i = 0; i < nx; i++)
                slab[i + nx * (j + n * k)] = blob((x0 + i + 0.5) / n, (j + 0.5) / n, (k + 0.5) / n, step);
}

/* This rank's particles of a side^3 lattice of the unit box (those whose
 * x falls in its share of [0, 1)), moved by `drift` along x, with their
 * smoothing lengths and the blob's values at `step`, as a push describes
 * them; `pos`, `h` and `val` hold side^3 particles. */
static gsenc_particles lattice_particles(int side, int size, double drift, int step, double *pos, double *h, double *val) {
    int np = 0;
    for (int k = 0; k < side; k++)
        for (int j = 0; j < side; j++)
            for (int i = 0; i < side; i++) {
                double x = (i + 0.5) / side, y = (j + 0.5) / side, z = (k + 0.5) / side;
                if (x * size < rank || x * size >= rank + 1) continue;
                pos[3 * np] = x + drift, pos[3 * np + 1] = y, pos[3 * np + 2] = z;
                h[np] = 1.3 / side;
                val[np] = blob(x, y, z, step);
                np++;
            }
    gsenc_particles p;
    memset(&p, 0, sizeof p);
    p.struct_size = sizeof p;
    p.dtype = GSENC_DTYPE_FLOAT64;
    p.count = (uint64_t)np;
    p.positions = pos;
    p.smoothing_length = h;
    p.values = val;
    return p;
}

#endif
