/* A simulation restarted from its checkpoint, as batch jobs run: each run of
 * this program advances a 24^3 field by three output steps, encoding each
 * into 1,000 Gaussians, and ends by writing its checkpoint: the solver's
 * step and the bytes of the field's last model (gsenc_encoder_model_bytes).
 * The next run reads them back and resumes the series
 * (gsenc_model_read_buffer, gsenc_encoder_resume): its first step is
 * warm-started from the last one, as if the run had not stopped, instead
 * of seeded afresh with the full schedule.
 * usage: restart CHECKPOINT_FILE   (run it again to go on) */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include "gsenc.h"

#define N 24
static double field[N][N][N]; /* [z][y][x], x fastest */

static int failed(const char *what) {
    char msg[512];
    gsenc_last_error(msg, sizeof msg);
    fprintf(stderr, "%s: %s\n", what, msg);
    return 1;
}

int main(int argc, char **argv) {
    if (argc != 2) {
        fprintf(stderr, "usage: restart CHECKPOINT_FILE\n");
        return 2;
    }
    gsenc_config cfg;
    gsenc_encoder *enc;
    cfg.struct_size = sizeof cfg;
    if (gsenc_config_init(&cfg) != GSENC_STATUS_OK) return 1;
    cfg.budget = 1000;
    if (gsenc_encoder_create(&cfg, &enc) != GSENC_STATUS_OK) return failed("create");

    /* The checkpoint: the last step done, then the model's bytes. */
    long long done = -1;
    FILE *f = fopen(argv[1], "rb");
    if (f) {
        long long size = 0;
        if (fscanf(f, "%lld %lld\n", &done, &size) != 2 || size <= 0) return fprintf(stderr, "%s: not a checkpoint\n", argv[1]), 1;
        unsigned char *bytes = malloc((size_t)size);
        if (!bytes || fread(bytes, 1, (size_t)size, f) != (size_t)size) return fprintf(stderr, "%s: truncated\n", argv[1]), 1;
        fclose(f);
        gsenc_model *last;
        if (gsenc_model_read_buffer(bytes, (size_t)size, &last) != GSENC_STATUS_OK) return failed("the checkpoint's model");
        if (gsenc_encoder_resume(enc, last) != GSENC_STATUS_OK) return failed("resume");
        gsenc_model_destroy(last);
        free(bytes);
        printf("resumed from step %lld\n", done);
    }

    gsenc_grid grid = {sizeof grid, GSENC_DTYPE_FLOAT64, field, {N, N, N}, {0, 0, 0}, {0, 0, 0}, 1.0 / N};
    for (long long step = done + 1; step <= done + 3; step++) {
        for (int z = 0; z < N; z++) for (int y = 0; y < N; y++) for (int x = 0; x < N; x++)
            field[z][y][x] = exp(-(pow(x - 6.0 - 1.5 * step, 2) + pow(y - 12.0, 2) + pow(z - 12.0, 2)) / 20.0);
        if (gsenc_push_grid(enc, "field", (uint64_t)step, 0.1 * step, &grid) != GSENC_STATUS_OK) return failed("push");
        gsenc_job job;
        job.struct_size = sizeof job;
        if (gsenc_wait(enc, NULL) != GSENC_STATUS_OK || gsenc_poll(enc, "field", (uint64_t)step, &job) != GSENC_STATUS_OK) return failed("encode");
        printf("step %lld: %.2f dB\n", step, job.psnr);
    }

    /* The new checkpoint, written to a temporary name and renamed. */
    size_t size = 0;
    if (gsenc_encoder_model_bytes(enc, "field", NULL, 0, &size) != GSENC_STATUS_OK) return failed("model bytes");
    unsigned char *bytes = malloc(size);
    if (!bytes || gsenc_encoder_model_bytes(enc, "field", bytes, size, &size) != GSENC_STATUS_OK) return failed("model bytes");
    char tmp[4096];
    snprintf(tmp, sizeof tmp, "%s.tmp", argv[1]);
    f = fopen(tmp, "wb");
    if (!f || fprintf(f, "%lld %zu\n", done + 3, size) < 0 || fwrite(bytes, 1, size, f) != size || fclose(f) != 0 || rename(tmp, argv[1]) != 0) {
        perror(argv[1]);
        return 1;
    }
    free(bytes);
    gsenc_encoder_destroy(enc);
    return 0;
}
