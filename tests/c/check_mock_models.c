/* Checks the models the mock solvers wrote, through the installed library
 * alone (built with pkg-config): for every field and step, the model file
 * exists, says its step, warm-started after step 0 (and, `auto`, the start it took), holds the budget, and
 * decodes to the mock field (mock_field.h, computed here independently of
 * the solver) with a PSNR above a floor taken from the field itself:
 * FLOOR dB above the PSNR of the best constant (the field's mean), i.e. the
 * model must remove all but 10^(-FLOOR/10) of the field's variance. Each
 * field has its own floor: particles and coarse cells sample the field less
 * well than the grid does.
 *
 * usage: check_mock_models DIR STEPS BUDGET FIELD:FLOOR...
 * Exit 0 when every check passes. */
#include <dirent.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gsenc.h"
#include "mock_field.h"

#define N 64

static int failed = 0;
#define CHECK(cond, ...)                                          \
    do {                                                          \
        if (!(cond)) {                                            \
            failed++;                                             \
            fprintf(stderr, "FAIL %s:%d: ", __FILE__, __LINE__); \
            fprintf(stderr, __VA_ARGS__);                         \
            fprintf(stderr, "\n");                                \
        }                                                         \
    } while (0)

int main(int argc, char **argv) {
    if (argc < 5) {
        fprintf(stderr, "usage: %s DIR STEPS BUDGET FIELD:FLOOR...\n", argv[0]);
        return 2;
    }
    const char *dir = argv[1];
    int steps = atoi(argv[2]);
    uint64_t budget = strtoull(argv[3], NULL, 10);
    int nfields = argc - 4;
    char names[16][64];
    double floors[16];
    if (nfields > 16) return 2;
    for (int f = 0; f < nfields; f++) {
        const char *colon = strchr(argv[4 + f], ':');
        size_t len = colon ? (size_t)(colon - argv[4 + f]) : strlen(argv[4 + f]);
        if (!colon || len >= sizeof names[f]) {
            fprintf(stderr, "field '%s' is not NAME:FLOOR\n", argv[4 + f]);
            return 2;
        }
        memcpy(names[f], argv[4 + f], len);
        names[f][len] = '\0';
        floors[f] = atof(colon + 1);
    }
    static float decoded[N * N * N];
    static double truth[N * N * N];
    for (int s = 0; s < steps; s++) {
        double t = s * MOCK_DT * 4;
        double mean = 0.0, var = 0.0, lo = INFINITY, hi = -INFINITY;
        for (int k = 0; k < N; k++)
            for (int j = 0; j < N; j++)
                for (int i = 0; i < N; i++) {
                    double x[3] = {(i + 0.5) / N, (j + 0.5) / N, (k + 0.5) / N};
                    double v = mock_field(x, t);
                    truth[(k * N + j) * N + i] = v;
                    mean += v;
                    lo = fmin(lo, v);
                    hi = fmax(hi, v);
                }
        mean /= N * N * N;
        for (int i = 0; i < N * N * N; i++) var += (truth[i] - mean) * (truth[i] - mean) / (N * N * N);
        double range = hi - lo, psnr_mean = 10.0 * log10(range * range / var);
        printf("step %2d  constant %.2f dB", s, psnr_mean);
        for (int f = 0; f < nfields; f++) {
            char path[4096];
            snprintf(path, sizeof path, "%s/%s_%06d.gsm", dir, names[f], s);
            gsenc_model *m = NULL;
            gsenc_status st = gsenc_model_read(path, &m);
            CHECK(st == GSENC_STATUS_OK, "%s: %s", path, gsenc_status_string(st));
            if (st != GSENC_STATUS_OK) continue;
            gsenc_model_info info = {.struct_size = sizeof info};
            CHECK(gsenc_model_info_get(m, &info) == GSENC_STATUS_OK, "info of %s", path);
            CHECK(info.step == (uint64_t)s, "%s says step %llu", path, (unsigned long long)info.step);
            CHECK(info.warm_started == (s > 0), "%s: warm_started %d at step %d", path, info.warm_started, s);
            /* The mock warm-starts `auto`: every warm step says what it took. */
            CHECK((s > 0) == (info.warm_taken >= GSENC_WARM_TAKEN_KEPT && info.warm_taken <= GSENC_WARM_TAKEN_FRESH) &&
                      (s > 0 || info.warm_taken == GSENC_WARM_TAKEN_NONE) && info.warm_moved <= budget && info.fell_back == 0,
                  "%s: warm_taken %d, warm_moved %u, fell_back %d at step %d", path, info.warm_taken, info.warm_moved,
                  info.fell_back, s);
            CHECK(info.count == budget, "%s holds %llu Gaussians, budget %llu", path, (unsigned long long)info.count,
                  (unsigned long long)budget);
            CHECK(fabs(info.time - t) < 1e-12, "%s: time %g, want %g", path, info.time, t);
            uint64_t dims[3] = {N, N, N};
            CHECK(gsenc_model_decode(m, dims, decoded, N * N * N) == GSENC_STATUS_OK, "decode %s", path);
            double se = 0.0;
            for (int i = 0; i < N * N * N; i++) se += (decoded[i] - truth[i]) * (decoded[i] - truth[i]);
            double psnr = 10.0 * log10(range * range / (se / (N * N * N)));
            printf("  %s %.2f dB", names[f], psnr);
            CHECK(psnr >= psnr_mean + floors[f], "%s: %.2f dB, below the floor %.2f dB (constant: %.2f dB)", path, psnr,
                  psnr_mean + floors[f], psnr_mean);
            gsenc_model_destroy(m);
        }
        printf("\n");
    }
    /* Exactly the models expected, and no temporary file left behind. */
    int files = 0;
    DIR *d = opendir(dir);
    CHECK(d != NULL, "cannot list %s", dir);
    for (struct dirent *e; d && (e = readdir(d));) {
        if (e->d_name[0] == '.') continue;
        files++;
        CHECK(strstr(e->d_name, ".gsm") && !strstr(e->d_name, "tmp"), "unexpected file %s", e->d_name);
    }
    if (d) closedir(d);
    CHECK(files == steps * nfields, "%d files in %s, want %d", files, dir, steps * nfields);
    printf("check_mock_models: %s, %d failed\n", failed ? "FAILED" : "ok", failed);
    return failed != 0;
}
