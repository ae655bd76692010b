/* The mock solver's field: a few Gaussian blobs of a scalar that move on
 * circles through the unit box and stretch and shrink as they go. Shared by
 * the C mock solver and by the test that checks its models (the Fortran mock
 * solver computes the same formula). Header-only. */
#ifndef GSENC_MOCK_FIELD_H
#define GSENC_MOCK_FIELD_H

#include <math.h>

#define MOCK_BLOBS 4
#define MOCK_DT 0.05

/* Blob b at time t: centre, per-axis widths, amplitude. */
static inline void mock_blob(int b, double t, double centre[3], double width[3], double *amplitude) {
    double phase = 1.7 * b, w = 1.0 + 0.35 * b;
    centre[0] = 0.5 + 0.22 * cos(w * t + phase);
    centre[1] = 0.5 + 0.22 * sin(w * t + phase);
    centre[2] = 0.5 + 0.15 * sin(0.5 * w * t + 2.0 * phase);
    width[0] = 0.06 + 0.02 * b + 0.02 * sin(2.0 * t + phase);
    width[1] = 0.06 + 0.01 * b + 0.02 * cos(1.5 * t + phase);
    width[2] = 0.05 + 0.015 * b;
    *amplitude = 1.0 + 0.5 * b;
}

/* The field at world point x, time t. */
static inline double mock_field(const double x[3], double t) {
    double f = 0.0;
    for (int b = 0; b < MOCK_BLOBS; b++) {
        double c[3], s[3], a, r2 = 0.0;
        mock_blob(b, t, c, s, &a);
        for (int k = 0; k < 3; k++) r2 += (x[k] - c[k]) * (x[k] - c[k]) / (s[k] * s[k]);
        f += a * exp(-0.5 * r2);
    }
    return f;
}

/* Distance from x to the nearest blob centre, in units of that blob's
 * largest width: where the cells are refined. */
static inline double mock_blob_distance(const double x[3], double t) {
    double best = INFINITY;
    for (int b = 0; b < MOCK_BLOBS; b++) {
        double c[3], s[3], a, r2 = 0.0;
        mock_blob(b, t, c, s, &a);
        double smax = fmax(s[0], fmax(s[1], s[2]));
        for (int k = 0; k < 3; k++) r2 += (x[k] - c[k]) * (x[k] - c[k]);
        best = fmin(best, sqrt(r2) / smax);
    }
    return best;
}

#endif
