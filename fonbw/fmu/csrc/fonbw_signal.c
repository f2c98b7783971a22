/* FMI 2.0 co-simulation interface of FonbwSignalNative: a sampled signal.
 *
 * The output y plays a table of samples, one per internal step dt: after k
 * internal steps from the start time y = table[k] (held at the last sample
 * past the end), so a master that reads y after each communication step
 * hands its inputs the table in step order with no work of its own per
 * step. The table is a text file named by the String parameter `file`, one
 * number per line, written with 17 significant digits so that a correctly
 * rounding strtod (glibc, macOS, the UCRT) reads every sample back bit for
 * bit. It is read when initialization starts and again when it ends if
 * `file` changed in between.
 *
 * Self-contained (libc and libm only); config.h (written by the builder)
 * holds INSTANTIATION_TOKEN and DEFAULT_DT. */
#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "config.h"
#include "fmi2Functions.h"

enum { VR_OUT = 1, VR_DT = 8, VR_FILE = 60 };

#define STEP_MULTIPLE_TOL 1e-6

typedef enum { ST_INSTANTIATED = 1, ST_INIT = 2, ST_STEP = 4, ST_TERMINATED = 8, ST_ERROR = 16 } Phase;
#define ANY (ST_INSTANTIATED | ST_INIT | ST_STEP | ST_TERMINATED | ST_ERROR)

typedef struct {
    char *name;
    fmi2CallbackFunctions cb;
    int logging;
    Phase phase;
    double time, dt;
    char *file;            /* the String parameter */
    char *loaded_from;     /* the file the table was read from (NULL: none) */
    double *table;
    size_t n, k;           /* samples; internal steps done */
} Instance;

static void logf_(Instance *c, fmi2Status st, const char *cat, const char *fmt, ...) {
    char buf[1024];
    va_list ap;
    if (!c->cb.logger || (st == fmi2OK && !c->logging)) return;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    c->cb.logger(c->cb.componentEnvironment, c->name, st, cat, "%s", buf);
}

#define BEGIN(fn, allowed)                                                            \
    Instance *c = (Instance *)comp;                                                   \
    if (!c) return fmi2Error;                                                         \
    if (!(c->phase & (allowed))) {                                                    \
        logf_(c, fmi2Error, "logStatusError", fn " is not allowed in this state");    \
        return fmi2Error;                                                             \
    }

static char *dup_str(const char *s) {
    char *d = malloc(strlen(s) + 1);
    if (d) strcpy(d, s);
    return d;
}

static void drop_table(Instance *c) {
    free(c->table); c->table = NULL; c->n = 0;
    free(c->loaded_from); c->loaded_from = NULL;
}

/* read the table named by `file`: 0, or -1 with an fmi2Error log line */
static int load_table(Instance *c) {
    FILE *f;
    char line[128], *end;
    size_t cap = 0, row = 0;
    drop_table(c);
    if (!c->file || !*c->file) {
        logf_(c, fmi2Error, "logStatusError", "invalid parameters: file is empty (no table of samples)");
        return -1;
    }
    if (!(f = fopen(c->file, "r"))) {
        logf_(c, fmi2Error, "logStatusError", "invalid parameters: cannot open file '%s'", c->file);
        return -1;
    }
    while (fgets(line, sizeof line, f)) {
        double v;
        row++;
        if (line[0] == '\n' || line[0] == '\0') continue;
        errno = 0;
        v = strtod(line, &end);
        while (*end == ' ' || *end == '\t' || *end == '\r' || *end == '\n') end++;
        if (end == line || *end || !isfinite(v)) {
            logf_(c, fmi2Error, "logStatusError", "invalid parameters: line %lu of '%s' is not a "
                  "finite number", (unsigned long)row, c->file);
            fclose(f); drop_table(c);
            return -1;
        }
        if (c->n == cap) {
            double *t = realloc(c->table, sizeof(double) * (cap = cap ? 2 * cap : 1024));
            if (!t) { fclose(f); drop_table(c); logf_(c, fmi2Error, "logStatusError", "out of memory"); return -1; }
            c->table = t;
        }
        c->table[c->n++] = v;
    }
    fclose(f);
    if (!c->n) {
        logf_(c, fmi2Error, "logStatusError", "invalid parameters: '%s' holds no sample", c->file);
        return -1;
    }
    c->loaded_from = dup_str(c->file);
    return 0;
}

static double output(const Instance *c) {
    if (!c->n) return 0.0;
    return c->table[c->k < c->n ? c->k : c->n - 1];
}

/* ------------------------------------------------------------ life cycle */

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String token, fmi2String resources,
                              const fmi2CallbackFunctions *functions, fmi2Boolean visible,
                              fmi2Boolean loggingOn) {
    Instance *c;
    (void)resources; (void)visible;
    if (!functions || !name) return NULL;
    c = calloc(1, sizeof *c);
    if (!c || !(c->name = dup_str(name)) || !(c->file = dup_str(""))) {
        if (c) free(c->name);
        free(c);
        return NULL;
    }
    c->cb = *functions;
    c->logging = loggingOn;
    if (type != fmi2CoSimulation || !token || strcmp(token, INSTANTIATION_TOKEN) != 0) {
        logf_(c, fmi2Error, "logStatusError", type != fmi2CoSimulation
              ? "only co-simulation is supported" : "the GUID does not match this FMU");
        free(c->file); free(c->name); free(c);
        return NULL;
    }
    c->phase = ST_INSTANTIATED;
    c->dt = DEFAULT_DT;
    return c;
}

void fmi2FreeInstance(fmi2Component comp) {
    Instance *c = (Instance *)comp;
    if (!c) return;
    drop_table(c);
    free(c->file);
    free(c->name);
    free(c);
}

fmi2Status fmi2SetDebugLogging(fmi2Component comp, fmi2Boolean on, size_t n, const fmi2String cats[]) {
    BEGIN("fmi2SetDebugLogging", ANY)
    (void)n; (void)cats;
    c->logging = on;
    return fmi2OK;
}

fmi2Status fmi2SetupExperiment(fmi2Component comp, fmi2Boolean tolDefined, fmi2Real tol,
                               fmi2Real start, fmi2Boolean stopDefined, fmi2Real stop) {
    BEGIN("fmi2SetupExperiment", ST_INSTANTIATED)
    (void)tolDefined; (void)tol; (void)stopDefined; (void)stop;
    c->time = start;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component comp) {
    BEGIN("fmi2EnterInitializationMode", ST_INSTANTIATED)
    /* read now so that the initial output is known during initialization */
    if (*c->file && load_table(c) != 0) { c->phase = ST_ERROR; return fmi2Error; }
    c->k = 0;
    c->phase = ST_INIT;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component comp) {
    BEGIN("fmi2ExitInitializationMode", ST_INIT)
    if (!(isfinite(c->dt) && c->dt > 0.0)) {
        logf_(c, fmi2Error, "logStatusError", "invalid parameters: dt = %.17g s must be a finite "
              "number > 0", c->dt);
        c->phase = ST_ERROR;
        return fmi2Error;
    }
    if ((!c->loaded_from || strcmp(c->loaded_from, c->file) != 0) && load_table(c) != 0) {
        c->phase = ST_ERROR;
        return fmi2Error;
    }
    c->k = 0;
    c->phase = ST_STEP;
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component comp) {
    BEGIN("fmi2Terminate", ST_STEP)
    c->phase = ST_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component comp) {
    char *empty;
    BEGIN("fmi2Reset", ANY)
    if (!(empty = dup_str(""))) return fmi2Error;
    drop_table(c);
    free(c->file);
    c->file = empty;
    c->dt = DEFAULT_DT;
    c->time = 0.0;
    c->k = 0;
    c->phase = ST_INSTANTIATED;
    return fmi2OK;
}

/* ------------------------------------------------------------- variables */

static fmi2Status bad_vr(Instance *c, const char *fn, fmi2ValueReference vr) {
    logf_(c, fmi2Error, "logStatusError", "%s: unknown value reference %u", fn, (unsigned)vr);
    return fmi2Error;
}

static fmi2Status fixed(Instance *c, const char *fn, fmi2ValueReference vr) {
    if (c->phase & (ST_INSTANTIATED | ST_INIT)) return fmi2OK;
    logf_(c, fmi2Error, "logStatusError", "%s: value reference %u is a fixed parameter, settable "
          "only before fmi2ExitInitializationMode", fn, (unsigned)vr);
    return fmi2Error;
}

fmi2Status fmi2GetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t n, fmi2Real v[]) {
    size_t k;
    BEGIN("fmi2GetReal", ANY & ~ST_ERROR)
    for (k = 0; k < n; k++) {
        if (vr[k] == VR_OUT) v[k] = output(c);
        else if (vr[k] == VR_DT) v[k] = c->dt;
        else return bad_vr(c, "fmi2GetReal", vr[k]);
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t n, const fmi2Real v[]) {
    size_t k;
    BEGIN("fmi2SetReal", ST_INSTANTIATED | ST_INIT | ST_STEP)
    for (k = 0; k < n; k++) {
        if (vr[k] != VR_DT) return bad_vr(c, "fmi2SetReal", vr[k]);
        if (fixed(c, "fmi2SetReal", vr[k]) != fmi2OK) return fmi2Error;
        c->dt = v[k];
    }
    return fmi2OK;
}

fmi2Status fmi2GetString(fmi2Component comp, const fmi2ValueReference vr[], size_t n, fmi2String v[]) {
    size_t k;
    BEGIN("fmi2GetString", ANY & ~ST_ERROR)
    for (k = 0; k < n; k++) {
        if (vr[k] != VR_FILE) return bad_vr(c, "fmi2GetString", vr[k]);
        v[k] = c->file;
    }
    return fmi2OK;
}

fmi2Status fmi2SetString(fmi2Component comp, const fmi2ValueReference vr[], size_t n, const fmi2String v[]) {
    size_t k;
    char *s;
    BEGIN("fmi2SetString", ST_INSTANTIATED | ST_INIT | ST_STEP)
    for (k = 0; k < n; k++) {
        if (vr[k] != VR_FILE) return bad_vr(c, "fmi2SetString", vr[k]);
        if (fixed(c, "fmi2SetString", vr[k]) != fmi2OK) return fmi2Error;
        if (!(s = dup_str(v[k] ? v[k] : ""))) return fmi2Error;
        free(c->file);
        c->file = s;
    }
    return fmi2OK;
}

fmi2Status fmi2GetInteger(fmi2Component comp, const fmi2ValueReference vr[], size_t n, fmi2Integer v[]) {
    BEGIN("fmi2GetInteger", ANY)
    (void)v;
    return n ? bad_vr(c, "fmi2GetInteger", vr[0]) : fmi2OK;
}

fmi2Status fmi2SetInteger(fmi2Component comp, const fmi2ValueReference vr[], size_t n, const fmi2Integer v[]) {
    BEGIN("fmi2SetInteger", ANY)
    (void)v;
    return n ? bad_vr(c, "fmi2SetInteger", vr[0]) : fmi2OK;
}

fmi2Status fmi2GetBoolean(fmi2Component comp, const fmi2ValueReference vr[], size_t n, fmi2Boolean v[]) {
    BEGIN("fmi2GetBoolean", ANY)
    (void)v;
    return n ? bad_vr(c, "fmi2GetBoolean", vr[0]) : fmi2OK;
}

fmi2Status fmi2SetBoolean(fmi2Component comp, const fmi2ValueReference vr[], size_t n, const fmi2Boolean v[]) {
    BEGIN("fmi2SetBoolean", ANY)
    (void)v;
    return n ? bad_vr(c, "fmi2SetBoolean", vr[0]) : fmi2OK;
}

/* ---------------------------------------------------------------- stepping */

fmi2Status fmi2DoStep(fmi2Component comp, fmi2Real t, fmi2Real h, fmi2Boolean noSetPrior) {
    double m;
    long k;
    BEGIN("fmi2DoStep", ST_STEP)
    (void)noSetPrior;
    m = h / c->dt;
    k = (m >= 0.5 && m < 1e15) ? (long)(m + 0.5) : 0;
    if (k < 1 || fabs(m - (double)k) > STEP_MULTIPLE_TOL) {
        logf_(c, fmi2Discard, "logStatusDiscard", "doStep at t=%.17g refused: communication step %.17g s "
              "is not a whole multiple of the internal step dt = %.17g s (ratio %.17g)", t, h, c->dt, m);
        return fmi2Discard;
    }
    c->k += (size_t)k;
    c->time = t + h;
    return fmi2OK;
}

fmi2Status fmi2CancelStep(fmi2Component comp) {
    BEGIN("fmi2CancelStep", ST_STEP)
    logf_(c, fmi2Error, "logStatusError", "fmi2CancelStep: doStep always completes synchronously");
    return fmi2Error;
}

static fmi2Status unsupported(Instance *c, const char *what) {
    logf_(c, fmi2Error, "logStatusError", "%s are not supported", what);
    return fmi2Error;
}

fmi2Status fmi2SetRealInputDerivatives(fmi2Component comp, const fmi2ValueReference vr[], size_t n,
                                       const fmi2Integer order[], const fmi2Real v[]) {
    BEGIN("fmi2SetRealInputDerivatives", ANY)
    (void)vr; (void)n; (void)order; (void)v;
    return unsupported(c, "input derivatives");
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component comp, const fmi2ValueReference vr[], size_t n,
                                        const fmi2Integer order[], fmi2Real v[]) {
    BEGIN("fmi2GetRealOutputDerivatives", ANY)
    (void)vr; (void)n; (void)order; (void)v;
    return unsupported(c, "output derivatives");
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component comp, const fmi2ValueReference u[], size_t nu,
                                        const fmi2ValueReference z[], size_t nz, const fmi2Real du[],
                                        fmi2Real dz[]) {
    BEGIN("fmi2GetDirectionalDerivative", ANY)
    (void)u; (void)nu; (void)z; (void)nz; (void)du; (void)dz;
    return unsupported(c, "directional derivatives");
}

fmi2Status fmi2GetStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Status *v) {
    BEGIN("fmi2GetStatus", ANY) (void)s; (void)v; return fmi2Discard;
}
fmi2Status fmi2GetRealStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Real *v) {
    BEGIN("fmi2GetRealStatus", ANY)
    if (s == fmi2LastSuccessfulTime) { *v = c->time; return fmi2OK; }
    return fmi2Discard;
}
fmi2Status fmi2GetIntegerStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Integer *v) {
    BEGIN("fmi2GetIntegerStatus", ANY) (void)s; (void)v; return fmi2Discard;
}
fmi2Status fmi2GetBooleanStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Boolean *v) {
    BEGIN("fmi2GetBooleanStatus", ANY)
    if (s == fmi2Terminated) { *v = fmi2False; return fmi2OK; }
    return fmi2Discard;
}
fmi2Status fmi2GetStringStatus(fmi2Component comp, const fmi2StatusKind s, fmi2String *v) {
    BEGIN("fmi2GetStringStatus", ANY) (void)s; (void)v; return fmi2Discard;
}

/* FMU state: not offered (canGetAndSetFMUstate is false in the model description) */

fmi2Status fmi2GetFMUstate(fmi2Component comp, fmi2FMUstate *state) {
    BEGIN("fmi2GetFMUstate", ANY) (void)state; return unsupported(c, "FMU states");
}
fmi2Status fmi2SetFMUstate(fmi2Component comp, fmi2FMUstate state) {
    BEGIN("fmi2SetFMUstate", ANY) (void)state; return unsupported(c, "FMU states");
}
fmi2Status fmi2FreeFMUstate(fmi2Component comp, fmi2FMUstate *state) {
    BEGIN("fmi2FreeFMUstate", ANY) (void)state; return unsupported(c, "FMU states");
}
fmi2Status fmi2SerializedFMUstateSize(fmi2Component comp, fmi2FMUstate state, size_t *size) {
    BEGIN("fmi2SerializedFMUstateSize", ANY) (void)state; (void)size; return unsupported(c, "FMU states");
}
fmi2Status fmi2SerializeFMUstate(fmi2Component comp, fmi2FMUstate state, fmi2Byte bytes[], size_t size) {
    BEGIN("fmi2SerializeFMUstate", ANY) (void)state; (void)bytes; (void)size;
    return unsupported(c, "FMU states");
}
fmi2Status fmi2DeSerializeFMUstate(fmi2Component comp, const fmi2Byte bytes[], size_t size, fmi2FMUstate *state) {
    BEGIN("fmi2DeSerializeFMUstate", ANY) (void)bytes; (void)size; (void)state;
    return unsupported(c, "FMU states");
}
