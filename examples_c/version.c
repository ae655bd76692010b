/* The smallest program that links gsenc: checks that the header's version
 * macros and the library's run-time version agree. Built and run by
 * tests/run-all.sh against the static library. */
#include <stdio.h>
#include <string.h>
#include "gsenc.h"

int main(void) {
    unsigned expected = GSENC_VERSION_MAJOR * 10000u + GSENC_VERSION_MINOR * 100u + GSENC_VERSION_PATCH;
    unsigned got = gsenc_version();
    printf("gsenc %s (%u)\n", gsenc_version_string(), got);
    if (got != expected) {
        fprintf(stderr, "header says %u, library says %u\n", expected, got);
        return 1;
    }
    char buf[32];
    snprintf(buf, sizeof buf, "%u.%u.%u", GSENC_VERSION_MAJOR, GSENC_VERSION_MINOR, GSENC_VERSION_PATCH);
    if (strcmp(buf, gsenc_version_string()) != 0) {
        fprintf(stderr, "version string %s != %s\n", gsenc_version_string(), buf);
        return 1;
    }
    return 0;
}
