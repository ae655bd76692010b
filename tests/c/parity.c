/* The C API and the command-line tool encode the same input into the same
 * model: this program makes particles and cells, writes their arrays as
 * raw float32 files into DIR, and encodes them through the C API with the
 * `full` schedule (where particles run 4,000 iterations, other inputs
 * 3,000) into DIR/capi/. tests/parity.sh then encodes the files with
 * `gsenc encode particles|cells` and compares the two models byte for byte.
 * Usage: parity DIR. Prints "parity-c: N passed, M failed". */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "gsenc.h"

static int passed, failed;
#define CHECK(cond, ...) do { if (cond) passed++; else { failed++; fprintf(stderr, "FAILED %s:%d: ", __FILE__, __LINE__); fprintf(stderr, __VA_ARGS__); fprintf(stderr, "\n"); } } while (0)

enum { NP = 600, NC = 512 };

static void save(const char *dir, const char *name, const float *a, size_t n) {
    char path[1024];
    snprintf(path, sizeof path, "%s/%s", dir, name);
    FILE *f = fopen(path, "wb");
    if (!f || fwrite(a, sizeof *a, n, f) != n || fclose(f) != 0) {
        fprintf(stderr, "cannot write %s\n", path);
        exit(2);
    }
}

/* A blob of value in the unit box. */
static float blob(float x, float y, float z) {
    float dx = x - 0.45f, dy = y - 0.55f, dz = z - 0.5f;
    return 1.0f + 4.0f * expf(-(dx * dx + dy * dy + dz * dz) / 0.05f);
}

int main(int argc, char **argv) {
    if (argc != 2) {
        fprintf(stderr, "usage: parity DIR\n");
        return 2;
    }
    const char *dir = argv[1];
    static float pos[3 * NP], h[NP], mass[NP], pval[NP], centres[3 * NC], edges[3 * NC], cval[NC];
    unsigned s = 12345;
    for (int i = 0; i < NP; i++) {
        for (int c = 0; c < 3; c++) {
            s = s * 1103515245u + 12345u;
            pos[3 * i + c] = (float)((s >> 8) & 0xffff) / 65536.0f;
        }
        h[i] = 0.06f;
        mass[i] = 1.0f + (float)(i % 3);
        pval[i] = blob(pos[3 * i], pos[3 * i + 1], pos[3 * i + 2]);
    }
    for (int i = 0; i < NC; i++) { /* an 8^3 grid of cubic cells over the unit box */
        int x = i % 8, y = i / 8 % 8, z = i / 64;
        centres[3 * i] = (x + 0.5f) / 8, centres[3 * i + 1] = (y + 0.5f) / 8, centres[3 * i + 2] = (z + 0.5f) / 8;
        edges[3 * i] = edges[3 * i + 1] = edges[3 * i + 2] = 1.0f / 8;
        cval[i] = blob(centres[3 * i], centres[3 * i + 1], centres[3 * i + 2]);
    }
    save(dir, "positions.f32", pos, 3 * NP);
    save(dir, "h.f32", h, NP);
    save(dir, "mass.f32", mass, NP);
    save(dir, "pval.f32", pval, NP);
    save(dir, "centres.f32", centres, 3 * NC);
    save(dir, "edges.f32", edges, 3 * NC);
    save(dir, "cval.f32", cval, NC);

    char out[1024];
    snprintf(out, sizeof out, "%s/capi", dir);
    gsenc_config cfg;
    memset(&cfg, 0, sizeof cfg);
    cfg.struct_size = sizeof cfg;
    CHECK(gsenc_config_init(&cfg) == GSENC_STATUS_OK, "config");
    cfg.budget = 40;
    cfg.schedule = GSENC_SCHEDULE_FULL;
    cfg.points = 256; /* the iterations stay the schedule's */
    cfg.dims[0] = cfg.dims[1] = cfg.dims[2] = 12;
    cfg.output_dir = out;
    gsenc_encoder *enc = NULL;
    CHECK(gsenc_encoder_create(&cfg, &enc) == GSENC_STATUS_OK, "create");

    gsenc_particles p;
    memset(&p, 0, sizeof p);
    p.struct_size = sizeof p;
    p.dtype = GSENC_DTYPE_FLOAT32;
    p.count = NP;
    p.positions = pos, p.smoothing_length = h, p.mass = mass, p.values = pval;
    CHECK(gsenc_push_particles(enc, "rho", 3, NAN, &p) == GSENC_STATUS_OK, "push particles");

    gsenc_cells c;
    memset(&c, 0, sizeof c);
    c.struct_size = sizeof c;
    c.dtype = GSENC_DTYPE_FLOAT32;
    c.layout = GSENC_CELLS_BOXES;
    c.count = NC;
    c.centres = centres, c.edges = edges, c.values = cval;
    CHECK(gsenc_push_cells(enc, "temp", 3, NAN, &c) == GSENC_STATUS_OK, "push cells");
    CHECK(gsenc_wait(enc, NULL) == GSENC_STATUS_OK, "wait");
    gsenc_encoder_destroy(enc);

    /* The iterations the C API ran: the schedule's, by input form. */
    const char *models[2] = {"rho_000003.gsm", "temp_000003.gsm"};
    const unsigned want[2] = {4000, 3000};
    for (int i = 0; i < 2; i++) {
        char path[1100];
        snprintf(path, sizeof path, "%s/%s", out, models[i]);
        gsenc_model *m = NULL;
        gsenc_model_info info;
        memset(&info, 0, sizeof info);
        info.struct_size = sizeof info;
        CHECK(gsenc_model_read(path, &m) == GSENC_STATUS_OK && gsenc_model_info_get(m, &info) == GSENC_STATUS_OK, "read %s", path);
        CHECK(info.iterations == want[i], "%s ran %u iterations, the full schedule is %u", models[i], info.iterations, want[i]);
        gsenc_model_destroy(m);
    }
    printf("parity-c: %d passed, %d failed\n", passed, failed);
    return failed != 0;
}
