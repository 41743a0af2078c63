/* What the FMI 2.0 C tests share as the importer: a logger that keeps the last message, the
 * callbacks, and make(name), which instantiates the FMU whose GUID the test defines first. */
#ifndef MAGLEV_TEST_FMI2_HOST_H
#define MAGLEV_TEST_FMI2_HOST_H

#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"

#ifndef GUID
#error "define GUID, the FMU's guid, before including fmi2_host.h"
#endif

static char last_log[1024];
static int n_logs = 0;

static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status, fmi2String category,
                   fmi2String fmt, ...) {
    (void)env; (void)name; (void)status; (void)category;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(last_log, sizeof last_log, fmt, ap);
    va_end(ap);
    n_logs++;
}

static const fmi2CallbackFunctions callbacks = {logger, calloc, free, NULL, NULL};

static int logged(const char *needle) { return strstr(last_log, needle) != NULL; }

static fmi2Component make(const char *name) {
    return fmi2Instantiate(name, fmi2CoSimulation, GUID, NULL, &callbacks, fmi2False, fmi2False);
}

#endif
