/* gsenc's log for C hosts (capi/log.rs): an encoder created by a thread
 * bound to one CPU, as a rank bound to one core is, logs a warning on the
 * standard error, after its rank, when GSENC_LOG asks for warnings, and
 * prints nothing when it is not set (a library on every rank of a job must
 * not print on each).
 * A GSENC_LOG that is not a filter logs warnings and says so. Linux only
 * (thread affinity). Run as `log on`, `log bad` and `log off`, one process
 * each (the log is set up once a process); built and run by
 * tests/run-all.sh; prints "c-log (MODE): N passed, M failed". */
#define _GNU_SOURCE /* sched_setaffinity, CPU_SET */
#include <pthread.h>
#include <sched.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include "gsenc.h"

static int passed, failed;
#define CHECK(cond, ...) do { if (cond) passed++; else { failed++; fprintf(stderr, "FAILED %s:%d: ", __FILE__, __LINE__); fprintf(stderr, __VA_ARGS__); fprintf(stderr, "\n"); } } while (0)

static char captured[8192];
static int created;

/* Binds this thread to the first CPU it may use, then creates and destroys
 * an encoder with the standard error sent to a file, read back into
 * `captured`. */
static void *create_bound(void *path) {
    cpu_set_t set;
    if (sched_getaffinity(0, sizeof set, &set) != 0) return NULL;
    int cpu = 0;
    while (cpu < CPU_SETSIZE && !CPU_ISSET(cpu, &set)) cpu++;
    CPU_ZERO(&set);
    CPU_SET(cpu, &set);
    if (sched_setaffinity(0, sizeof set, &set) != 0) return NULL;
    fflush(stderr);
    int saved = dup(2);
    FILE *f = fopen((const char *)path, "w+");
    if (saved < 0 || f == NULL) return NULL;
    dup2(fileno(f), 2);
    gsenc_config cfg;
    cfg.struct_size = sizeof cfg;
    gsenc_config_init(&cfg);
    cfg.budget = 10;
    cfg.rank = 3;
    cfg.backend = GSENC_BACKEND_CPU;
    gsenc_encoder *enc = NULL;
    created = gsenc_encoder_create(&cfg, &enc) == GSENC_STATUS_OK;
    gsenc_encoder_destroy(enc);
    fflush(stderr);
    dup2(saved, 2);
    close(saved);
    rewind(f);
    size_t n = fread(captured, 1, sizeof captured - 1, f);
    captured[n] = 0;
    fclose(f);
    return NULL;
}

int main(int argc, char **argv) {
    const char *mode = argc > 1 ? argv[1] : "off";
    int on = strcmp(mode, "on") == 0, bad = strcmp(mode, "bad") == 0;
    if (on) setenv("GSENC_LOG", "warn", 1);
    else if (bad) setenv("GSENC_LOG", "gsenc=loud", 1); /* not a filter: warnings, and says so */
    else unsetenv("GSENC_LOG");
    const char *dir = getenv("GSENC_CAPI_TMP") ? getenv("GSENC_CAPI_TMP") : "/tmp";
    char path[512];
    snprintf(path, sizeof path, "%s/gsenc-log-%d.txt", dir, (int)getpid());
    pthread_t t;
    CHECK(pthread_create(&t, NULL, create_bound, path) == 0, "thread");
    pthread_join(t, NULL);
    remove(path);
    CHECK(created, "the encoder was not created");
    if (on || bad)
        CHECK((on ? strncmp(captured, "gsenc[rank 3] ", 14) == 0 : strstr(captured, "\ngsenc[rank 3] ") != NULL) && strstr(captured, "may run on CPU") != NULL && strstr(captured, "GSENC_ENCODER_CPUS") != NULL
                  && strstr(captured, "WARN") != NULL,
              "no warning of the shared CPU, after its rank, on the standard error: '%s'", captured);
    if (bad)
        CHECK(strstr(captured, "GSENC_LOG=\"gsenc=loud\" is not a filter") != NULL, "no word of the bad filter: '%s'", captured);
    if (!on && !bad)
        CHECK(captured[0] == 0, "printed without GSENC_LOG: '%s'", captured);
    printf("c-log (%s): %d passed, %d failed\n", mode, passed, failed);
    return failed != 0;
}
