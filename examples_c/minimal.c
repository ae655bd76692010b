/* The smallest in-situ use of gsenc: a 32^3 field for three steps, each
 * encoded into 2,000 Gaussians (warm-started from the step before) and
 * written to the current folder as field_STEP.gsm. */
#include <math.h>
#include <stdio.h>
#include "gsenc.h"

#define N 32
static double field[N][N][N]; /* [z][y][x], x fastest */

int main(void) {
    gsenc_config cfg = {sizeof cfg};
    gsenc_encoder *enc;
    if (gsenc_config_init(&cfg) != GSENC_STATUS_OK) return 1;
    cfg.budget = 2000;
    cfg.output_dir = ".";
    if (gsenc_encoder_create(&cfg, &enc) != GSENC_STATUS_OK) return 1;
    gsenc_grid grid = {sizeof grid, GSENC_DTYPE_FLOAT64, field, {N, N, N}, {0, 0, 0}, {0, 0, 0}, 1.0 / N};
    for (int step = 0; step < 3; step++) {
        for (int z = 0; z < N; z++) for (int y = 0; y < N; y++) for (int x = 0; x < N; x++)
            field[z][y][x] = exp(-(pow(x - 10.0 - 4 * step, 2) + pow(y - 16.0, 2) + pow(z - 16.0, 2)) / 30.0);
        double psnr; uint64_t s;
        if (gsenc_push_grid(enc, "field", step, 0.1 * step, &grid) != GSENC_STATUS_OK || gsenc_wait(enc, NULL) != GSENC_STATUS_OK
            || gsenc_encoder_last_step(enc, "field", &s, &psnr) != GSENC_STATUS_OK) {
            char msg[256]; gsenc_last_error(msg, sizeof msg); fprintf(stderr, "gsenc: %s\n", msg); return 1;
        }
        printf("step %d: %.2f dB\n", step, psnr);
    }
    gsenc_encoder_destroy(enc);
    return 0;
}
