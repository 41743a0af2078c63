/* A temporary resources folder for the C tests (a rig's start_values.txt, a calibrated FMU's guid.txt), on
 * Linux and in the Windows build (cross-compiled with mingw-w64, run under wine). The including file defines
 * _POSIX_C_SOURCE 200809L before its first #include, for mkdtemp. Inline: a test may use some of them only. */
#ifndef MAGLEV_TEST_TEMP_DIR_H
#define MAGLEV_TEST_TEMP_DIR_H

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#ifdef _WIN32
#include <direct.h>
#include <process.h>
#include <windows.h>
#endif

/* A new folder named after tag: dir, with '/' separators; NULL when it cannot be made. */
static inline char *make_temp_dir(char *dir, size_t len, const char *tag) {
#ifdef _WIN32
    char base[MAX_PATH + 1];
    DWORD n = GetTempPathA(sizeof base, base); /* ends with a separator */
    if (n == 0 || n >= sizeof base) return NULL;
    snprintf(dir, len, "%smaglev_%s_%d", base, tag, _getpid());
    for (char *p = dir; *p; p++)
        if (*p == '\\') *p = '/';
    return _mkdir(dir) == 0 ? dir : NULL;
#else
    snprintf(dir, len, "/tmp/maglev_%s_XXXXXX", tag);
    return mkdtemp(dir);
#endif
}

static inline void remove_dir(const char *dir) {
#ifdef _WIN32
    _rmdir(dir);
#else
    rmdir(dir);
#endif
}

/* Writes text to path: 0, or -1 when the file cannot be written. */
static inline int write_text(const char *path, const char *text) {
    FILE *fp = fopen(path, "w");
    if (!fp) return -1;
    int rc = fputs(text, fp) < 0 ? -1 : 0;
    return fclose(fp) ? -1 : rc;
}

/* The file: URI of a folder (FMI 2.0's fmuResourceLocation): file:///tmp/x on Linux, file:///C:/x on Windows. */
static inline void folder_uri(const char *dir, char *uri, size_t len) {
    snprintf(uri, len, "file://%s%s", dir[0] == '/' ? "" : "/", dir);
}

#endif
