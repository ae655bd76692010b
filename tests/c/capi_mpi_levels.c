/* MPI at too low a thread level, and after MPI_Finalize: gsenc_encoder_create_mpi
 * refuses with GSENC_STATUS_MPI and a message that says why (tests/mpi.sh). */
#include "gsenc.h"
#include <mpi.h>
#include <stdio.h>
#include <string.h>

static int failures = 0, passes = 0;
#define CHECK(cond, ...) do { if (cond) { passes++; } else { failures++; fprintf(stderr, "FAIL line %d: ", __LINE__); fprintf(stderr, __VA_ARGS__); fputc('\n', stderr); } } while (0)

static const char *last_error(void) {
    static char buf[1024];
    gsenc_last_error(buf, sizeof buf);
    return buf;
}

int main(int argc, char **argv) {
    gsenc_config cfg;
    cfg.struct_size = sizeof cfg;
    gsenc_config_init(&cfg);
    int provided = -1;
    MPI_Init_thread(&argc, &argv, MPI_THREAD_SINGLE, &provided);
    gsenc_encoder *enc = (gsenc_encoder *)1;
    gsenc_status s = gsenc_encoder_create_mpi(&cfg, MPI_Comm_c2f(MPI_COMM_WORLD), &enc);
    if (provided == MPI_THREAD_SINGLE)
        CHECK(s == GSENC_STATUS_MPI && enc == NULL && strstr(last_error(), "MPI_THREAD_SINGLE") != NULL, "at MPI_THREAD_SINGLE: %s: %s",
              gsenc_status_string(s), last_error());
    else
        printf("capi_mpi_levels: MPI gave thread level %d for SINGLE; that check is skipped\n", provided), gsenc_encoder_destroy(enc);
    MPI_Finalize();
    enc = (gsenc_encoder *)1;
    s = gsenc_encoder_create_mpi(&cfg, 0, &enc);
    CHECK(s == GSENC_STATUS_MPI && enc == NULL && strstr(last_error(), "finalised") != NULL, "after MPI_Finalize: %s: %s", gsenc_status_string(s),
          last_error());
    printf("c-mpi-levels: %d passed, %d failed\n", passes, failures);
    return failures == 0 ? 0 : 1;
}
