/* An exit() from native code (an FMU) while Python runs is not a normal end: say so, and end with
 * a non-zero code. Python's own shutdown disarms the guard first (bridge/fmu/exit_guard.py). */
#define _DEFAULT_SOURCE
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

static volatile int armed = 0;
static char note[1024];

static void report(int status) {
    char text[1400];
    int n = snprintf(text, sizeof text, "%s (exit status %d)\n", note, status);
    if (n > 0) {
        ssize_t written = write(2, text, (size_t)(n < (int)sizeof text ? n : (int)sizeof text - 1));
        (void)written;
    }
}

#ifdef __GLIBC__
static void guard(int status, void* arg) {
    (void)arg;
    if (!armed) return;
    report(status);
    _exit(status != 0 ? status : 70);
}
#else
static void guard(void) {
    if (!armed) return;
    report(-1);
    _exit(70);
}
#endif

int exit_guard_install(const char* text) {
    strncpy(note, text, sizeof note - 1);
#ifdef __GLIBC__
    return on_exit(guard, NULL);
#else
    return atexit(guard);
#endif
}

void exit_guard_arm(int on) { armed = on; }
