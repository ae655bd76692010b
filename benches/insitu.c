/* In-situ benchmark: a mock solver on a 128^3 float grid that
 * pushes its field to gsenc every step and never waits for the encode.
 *
 * Each solver step recomputes the moving blobs of examples_c/mock_field.h
 * (one exp per blob per cell) and relaxes the field with SWEEPS Jacobi
 * sweeps of a 7-point stencil: memory-bound work like a real solver's. With
 * ENCODE=1 every step's field is pushed (the encoder runs on its own pool
 * of `threads` threads, beside the solver's thread) and the models are
 * written to OUT_DIR; the solver only waits once, after its last step.
 *
 * usage: insitu OUT_DIR STEPS ENCODE [SWEEPS [BUDGET [ITERATIONS [WARM_ITERATIONS [THREADS]]]]]
 * Prints one JSON line: per-step solver times (compute, push), push
 * latency median and max, the final wait, and encode throughput. */
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "gsenc.h"
#include "mock_field.h"

#define N 128

static double now(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec + 1e-9 * ts.tv_nsec;
}

static int cmp(const void *a, const void *b) {
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static double median(double *v, int n) {
    qsort(v, (size_t)n, sizeof *v, cmp);
    return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

static int check(gsenc_status s, const char *what) {
    if (s == GSENC_STATUS_OK) return 0;
    char msg[1024];
    gsenc_last_error(msg, sizeof msg);
    fprintf(stderr, "insitu: %s: %s: %s\n", what, gsenc_status_string(s), msg);
    return 1;
}

/* One solver step: the blobs at time t, then `sweeps` Jacobi sweeps. */
static void solver_step(float *u, float *tmp, double t, int sweeps) {
    for (int k = 0; k < N; k++)
        for (int j = 0; j < N; j++)
            for (int i = 0; i < N; i++) {
                double x[3] = {(i + 0.5) / N, (j + 0.5) / N, (k + 0.5) / N};
                u[((size_t)k * N + j) * N + i] = (float)mock_field(x, t);
            }
    for (int s = 0; s < sweeps; s++) {
        for (int k = 1; k < N - 1; k++)
            for (int j = 1; j < N - 1; j++)
                for (int i = 1; i < N - 1; i++) {
                    size_t c = ((size_t)k * N + j) * N + i;
                    tmp[c] = 0.4f * u[c] + 0.1f * (u[c - 1] + u[c + 1] + u[c - N] + u[c + N] + u[c - N * N] + u[c + N * N]);
                }
        memcpy(u, tmp, sizeof(float) * N * N * N);
    }
}

int main(int argc, char **argv) {
    if (argc < 4) {
        fprintf(stderr, "usage: %s OUT_DIR STEPS ENCODE [SWEEPS [BUDGET [ITERATIONS [WARM_ITERATIONS [THREADS]]]]]\n", argv[0]);
        return 2;
    }
    int steps = atoi(argv[2]), encode = atoi(argv[3]);
    int sweeps = argc > 4 ? atoi(argv[4]) : 20;
    gsenc_config cfg = {.struct_size = sizeof cfg};
    if (check(gsenc_config_init(&cfg), "config")) return 1;
    cfg.budget = argc > 5 ? strtoull(argv[5], NULL, 10) : 4000;
    cfg.iterations = argc > 6 ? (uint32_t)atoi(argv[6]) : 400;
    cfg.warm_iterations = argc > 7 ? (uint32_t)atoi(argv[7]) : 200;
    cfg.threads = argc > 8 ? (uint32_t)atoi(argv[8]) : 1;
    cfg.schedule = GSENC_SCHEDULE_SHORT;
    cfg.warm_start = GSENC_WARM_DENSE;
    cfg.fixed_range = 1;
    cfg.value_min = 0.0;
    cfg.value_max = 4.0;
    cfg.output_dir = argv[1];
    cfg.when_full = GSENC_QUEUE_BLOCK;
    gsenc_encoder *enc = NULL;
    if (encode && check(gsenc_encoder_create(&cfg, &enc), "create")) return 1;
    /* The grid's copy readied before the first push, as a solver would do
     * once at start-up (INSITU_NO_RESERVE=1 leaves it out, to compare). */
    const char *no_reserve = getenv("INSITU_NO_RESERVE");
    int reserve = !(no_reserve && strcmp(no_reserve, "1") == 0);
    if (encode && reserve && check(gsenc_encoder_reserve(enc, (uint64_t)N * N * N), "reserve")) return 1;

    float *u = malloc(sizeof(float) * N * N * N), *tmp = calloc((size_t)N * N * N, sizeof(float));
    double *compute = malloc(sizeof(double) * steps), *push = calloc((size_t)steps, sizeof(double));
    if (!u || !tmp || !compute || !push) return 1;
    gsenc_grid g = {.struct_size = sizeof g, .dtype = GSENC_DTYPE_FLOAT32, .data = u, .extents = {N, N, N}, .spacing = 1.0 / N};
    double t_start = now();
    for (int s = 0; s < steps; s++) {
        double t0 = now();
        solver_step(u, tmp, s * MOCK_DT * 4, sweeps);
        double t1 = now();
        compute[s] = t1 - t0;
        if (encode) {
            if (check(gsenc_push_grid(enc, "blobs", (uint64_t)s, s * MOCK_DT * 4, &g), "push")) return 1;
            push[s] = now() - t1;
        }
    }
    double t_solver = now() - t_start, t_wait = 0.0;
    int failed = 0;
    if (encode) {
        double t0 = now();
        failed = check(gsenc_wait(enc, NULL), "wait");
        t_wait = now() - t0;
    }
    double t_total = now() - t_start;
    double psnr = 0.0;
    uint64_t last = 0;
    if (encode && !failed) failed = check(gsenc_encoder_last_step(enc, "blobs", &last, &psnr), "last_step");
    double step_sum = 0.0, push_max = 0.0, push_max_later = 0.0;
    for (int s = 0; s < steps; s++) {
        step_sum += compute[s] + push[s];
        if (push[s] > push_max) push_max = push[s];
        if (s > 0 && push[s] > push_max_later) push_max_later = push[s];
    }
    double push_median = median(push, steps), compute_median = median(compute, steps);
    printf("{\"steps\":%d,\"encode\":%d,\"reserve\":%d,\"sweeps\":%d,\"budget\":%llu,\"threads\":%u,"
           "\"compute_median_s\":%.4f,\"step_mean_s\":%.4f,\"push_median_ms\":%.3f,\"push_max_ms\":%.3f,\"push_max_after_first_ms\":%.3f,"
           "\"solver_s\":%.3f,\"final_wait_s\":%.3f,\"total_s\":%.3f,\"encode_steps_per_s\":%.4f,\"last_psnr\":%.2f}\n",
           steps, encode, reserve, sweeps, (unsigned long long)cfg.budget, cfg.threads, compute_median, step_sum / steps,
           1e3 * push_median, 1e3 * push_max, 1e3 * push_max_later, t_solver, t_wait, t_total, encode ? steps / t_total : 0.0, psnr);
    gsenc_encoder_destroy(enc);
    free(u);
    free(tmp);
    free(compute);
    free(push);
    return failed;
}
