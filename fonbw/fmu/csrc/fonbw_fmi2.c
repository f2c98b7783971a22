/* FMI 2.0 co-simulation interface of the fonbw native FMUs: life cycle,
 * variable access, stepping and the FMU state, one source for every kind
 * (fonbw_instance.h; the per-model parts in fonbw_model.c). Every entry
 * point checks the instance and its state in one place (BEGIN). */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fonbw_instance.h"

#define STEP_MULTIPLE_TOL 1e-6
#define STATE_MAGIC 4607863412.0

void fonbw_log(Instance *c, fmi2Status st, const char *cat, const char *fmt, ...) {
    char buf[1024];
    va_list ap;
    if (!c->cb.logger || (st == fmi2OK && !c->logging)) return;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    c->cb.logger(c->cb.componentEnvironment, c->name, st, cat, "%s", buf);
}

/* one place for the instance and state checks of every entry point */
#define BEGIN(fn, allowed)                                                                    \
    Instance *c = (Instance *)comp;                                                           \
    if (!c) return fmi2Error;                                                                 \
    if (!(c->phase & (allowed))) {                                                            \
        fonbw_log(c, fmi2Error, "logStatusError", fn " is not allowed in this state");        \
        return fmi2Error;                                                                     \
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
    if (!c || !(c->name = malloc(strlen(name) + 1))) { free(c); return NULL; }
    strcpy(c->name, name);
    c->cb = *functions;
    c->logging = loggingOn;
    if (type != fmi2CoSimulation || !token || strcmp(token, INSTANTIATION_TOKEN) != 0) {
        fonbw_log(c, fmi2Error, "logStatusError", type != fmi2CoSimulation
              ? "only co-simulation is supported" : "the GUID does not match this FMU");
        free(c->name); free(c);
        return NULL;
    }
    c->phase = ST_INSTANTIATED;
    inst_set_defaults(c);
    return c;
}

void fmi2FreeInstance(fmi2Component comp) {
    Instance *c = (Instance *)comp;
    if (!c) return;
    inst_release(c);
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
    if (inst_enter_init(c) != 0) { c->phase = ST_ERROR; return fmi2Error; }
    c->phase = ST_INIT;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component comp) {
    BEGIN("fmi2ExitInitializationMode", ST_INIT)
    if (inst_build_model(c) != 0) { c->phase = ST_ERROR; return fmi2Error; }
    c->r[VR_OUT] = 0.0;
    c->i[VR_STATUS] = 0;
    c->bad_before = 0;
#if MODEL_KIND == KIND_COMP && !PASS_THROUGH
    {
        double slope = c->r[VR_KU] + c->r[VR_KH] * c->r[VR_RHO] * pow(c->r[VR_DT], c->r[VR_LAM2] - c->r[VR_LAM1]);
        if (!(slope > 0.0))
            fonbw_log(c, fmi2Warning, "logStatusWarning", "the model is not invertible at this step: its "
                  "one-step slope ku1 + kh*rho*dt^(lam2-lam1) = %.6g um/V (small h) is <= 0, so the "
                  "per-step inverse is unstable; expect saturated or unconverged samples (see the "
                  "status output)", slope);
    }
#endif
    c->phase = ST_STEP;
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component comp) {
    BEGIN("fmi2Terminate", ST_STEP)
    c->phase = ST_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component comp) {
    BEGIN("fmi2Reset", ANY)
    inst_release(c);
    inst_set_defaults(c);
    c->time = 0.0;
    c->phase = ST_INSTANTIATED;
    return fmi2OK;
}

/* ------------------------------------------------------------- variables */

static fmi2Status bad_vr(Instance *c, const char *fn, fmi2ValueReference vr) {
    fonbw_log(c, fmi2Error, "logStatusError", "%s: unknown value reference %u", fn, (unsigned)vr);
    return fmi2Error;
}

/* a parameter may change until initialization ends (fixed variability) */
static fmi2Status may_set(Instance *c, const char *fn, fmi2ValueReference vr) {
    if (inst_is_input((int)vr)) return fmi2OK;
    if (!inst_is_param((int)vr)) {
        fonbw_log(c, fmi2Error, "logStatusError", "%s: value reference %u is not an input or parameter",
              fn, (unsigned)vr);
        return fmi2Error;
    }
    if (!(c->phase & (ST_INSTANTIATED | ST_INIT))) {
        fonbw_log(c, fmi2Error, "logStatusError", "%s: value reference %u is a fixed parameter, "
              "settable only before fmi2ExitInitializationMode", fn, (unsigned)vr);
        return fmi2Error;
    }
    return fmi2OK;
}

fmi2Status fmi2GetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t n, fmi2Real v[]) {
    size_t k;
    BEGIN("fmi2GetReal", ANY & ~ST_ERROR)
    for (k = 0; k < n; k++) {
        if (vr[k] >= NVR || !inst_is_real((int)vr[k])) return bad_vr(c, "fmi2GetReal", vr[k]);
        v[k] = vr[k] == VR_OUT ? inst_output(c) : c->r[vr[k]];
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t n, const fmi2Real v[]) {
    size_t k;
    BEGIN("fmi2SetReal", ST_INSTANTIATED | ST_INIT | ST_STEP)
    for (k = 0; k < n; k++) {
        if (vr[k] >= NVR || !inst_is_real((int)vr[k])) return bad_vr(c, "fmi2SetReal", vr[k]);
        if (may_set(c, "fmi2SetReal", vr[k]) != fmi2OK) return fmi2Error;
        c->r[vr[k]] = v[k];
    }
    return fmi2OK;
}

fmi2Status fmi2GetInteger(fmi2Component comp, const fmi2ValueReference vr[], size_t n, fmi2Integer v[]) {
    size_t k;
    BEGIN("fmi2GetInteger", ANY & ~ST_ERROR)
    for (k = 0; k < n; k++) {
        if (vr[k] >= NVR || !inst_is_int((int)vr[k])) return bad_vr(c, "fmi2GetInteger", vr[k]);
        v[k] = c->i[vr[k]];
    }
    return fmi2OK;
}

fmi2Status fmi2SetInteger(fmi2Component comp, const fmi2ValueReference vr[], size_t n, const fmi2Integer v[]) {
    size_t k;
    BEGIN("fmi2SetInteger", ST_INSTANTIATED | ST_INIT | ST_STEP)
    for (k = 0; k < n; k++) {
        if (vr[k] >= NVR || !inst_is_int((int)vr[k])) return bad_vr(c, "fmi2SetInteger", vr[k]);
        if (may_set(c, "fmi2SetInteger", vr[k]) != fmi2OK) return fmi2Error;
        c->i[vr[k]] = v[k];
    }
    return fmi2OK;
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

fmi2Status fmi2GetString(fmi2Component comp, const fmi2ValueReference vr[], size_t n, fmi2String v[]) {
    size_t k;
    int count, *slot;
    const char **names;
    char **text;
    BEGIN("fmi2GetString", ANY & ~ST_ERROR)
    for (k = 0; k < n; k++) {
        if (vr[k] < NVR && (text = inst_text(c, (int)vr[k]))) { v[k] = *text ? *text : ""; continue; }
        if (vr[k] >= NVR || !(names = inst_string_names(c, (int)vr[k], &count, &slot)))
            return bad_vr(c, "fmi2GetString", vr[k]);
        v[k] = names[*slot];
    }
    return fmi2OK;
}

fmi2Status fmi2SetString(fmi2Component comp, const fmi2ValueReference vr[], size_t n, const fmi2String v[]) {
    size_t k;
    int e, count, *slot;
    const char **names;
    char **text, *dup;
    BEGIN("fmi2SetString", ST_INSTANTIATED | ST_INIT | ST_STEP)
    for (k = 0; k < n; k++) {
        if (vr[k] < NVR && (text = inst_text(c, (int)vr[k]))) {
            if (may_set(c, "fmi2SetString", vr[k]) != fmi2OK) return fmi2Error;
            if (!(dup = malloc(strlen(v[k] ? v[k] : "") + 1))) {
                fonbw_log(c, fmi2Error, "logStatusError", "out of memory");
                return fmi2Error;
            }
            strcpy(dup, v[k] ? v[k] : "");
            free(*text);
            *text = dup;
            continue;
        }
        if (vr[k] >= NVR || !(names = inst_string_names(c, (int)vr[k], &count, &slot)))
            return bad_vr(c, "fmi2SetString", vr[k]);
        if (may_set(c, "fmi2SetString", vr[k]) != fmi2OK) return fmi2Error;
        for (e = 0; e < count; e++) if (v[k] && strcmp(v[k], names[e]) == 0) break;
        if (e == count) {
            fonbw_log(c, fmi2Error, "logStatusError", "invalid parameters: '%s' is not one of %s, %s, %s%s",
                  v[k] ? v[k] : "(null)", names[0], names[1], names[2], vr[k] == VR_MEMORY
                  ? " (oustaloup is not available in the native FMUs)" : "");
            return fmi2Error;
        }
        *slot = e;
    }
    return fmi2OK;
}

/* ---------------------------------------------------------------- stepping */

fmi2Status fmi2DoStep(fmi2Component comp, fmi2Real t, fmi2Real h, fmi2Boolean noSetPrior) {
    double m;
    long k;
    BEGIN("fmi2DoStep", ST_STEP)
    (void)noSetPrior;
    m = h / c->r[VR_DT];
    k = (m >= 0.5 && m < 1e15) ? (long)(m + 0.5) : 0;
    if (k < 1 || fabs(m - (double)k) > STEP_MULTIPLE_TOL) {
        fonbw_log(c, fmi2Discard, "logStatusDiscard", "doStep at t=%.17g refused: communication step %.17g s "
              "is not a whole multiple of the internal step dt = %.17g s (ratio %.17g); no resampling "
              "is done", t, h, c->r[VR_DT], m);
        return fmi2Discard;
    }
    if (!isfinite(c->r[VR_IN]) || (MODEL_KIND == KIND_PID && !(isfinite(c->r[VR_Y]) && isfinite(c->r[VR_UFF])))) {
        fonbw_log(c, fmi2Discard, "logStatusDiscard", "doStep at t=%.17g refused: an input is not finite", t);
        return fmi2Discard;
    }
#if MODEL_KIND == KIND_COMP && !PASS_THROUGH
    {
        double bad0 = c->comp.n_sat + c->comp.n_fail;
        inst_steps(c, k);
        if (c->comp.n_sat + c->comp.n_fail > bad0) {
            if (!c->bad_before)
                fonbw_log(c, fmi2Warning, "logStatusWarning", "at t=%.17g y_ref=%.17g um: %s (u = %.17g V); "
                      "further samples of this episode are not logged, see the status output", t,
                      c->r[VR_IN], c->comp.status == COMP_SAT_LOW ? "saturated at u_min" :
                      c->comp.status == COMP_SAT_HIGH ? "saturated at u_max" : "not converged",
                      c->r[VR_OUT]);
            c->bad_before = 1;
        } else c->bad_before = 0;
    }
#else
    inst_steps(c, k);
#endif
    c->time = t + h;
    return fmi2OK;
}

fmi2Status fmi2CancelStep(fmi2Component comp) {
    BEGIN("fmi2CancelStep", ST_STEP)
    fonbw_log(c, fmi2Error, "logStatusError", "fmi2CancelStep: doStep always completes synchronously");
    return fmi2Error;
}

fmi2Status fmi2SetRealInputDerivatives(fmi2Component comp, const fmi2ValueReference vr[], size_t n,
                                       const fmi2Integer order[], const fmi2Real v[]) {
    BEGIN("fmi2SetRealInputDerivatives", ANY)
    (void)vr; (void)n; (void)order; (void)v;
    fonbw_log(c, fmi2Error, "logStatusError", "input derivatives are not supported");
    return fmi2Error;
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component comp, const fmi2ValueReference vr[], size_t n,
                                        const fmi2Integer order[], fmi2Real v[]) {
    BEGIN("fmi2GetRealOutputDerivatives", ANY)
    (void)vr; (void)n; (void)order; (void)v;
    fonbw_log(c, fmi2Error, "logStatusError", "output derivatives are not supported");
    return fmi2Error;
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component comp, const fmi2ValueReference u[], size_t nu,
                                        const fmi2ValueReference z[], size_t nz, const fmi2Real du[],
                                        fmi2Real dz[]) {
    BEGIN("fmi2GetDirectionalDerivative", ANY)
    (void)u; (void)nu; (void)z; (void)nz; (void)du; (void)dz;
    fonbw_log(c, fmi2Error, "logStatusError", "directional derivatives are not supported");
    return fmi2Error;
}

static fmi2Status no_status(Instance *c) {
    fonbw_log(c, fmi2Error, "logStatusError", "doStep is synchronous: there is no pending status");
    return fmi2Discard;
}

fmi2Status fmi2GetStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Status *v) {
    BEGIN("fmi2GetStatus", ANY) (void)s; (void)v; return no_status(c);
}
fmi2Status fmi2GetRealStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Real *v) {
    BEGIN("fmi2GetRealStatus", ANY)
    if (s == fmi2LastSuccessfulTime) { *v = c->time; return fmi2OK; }
    return no_status(c);
}
fmi2Status fmi2GetIntegerStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Integer *v) {
    BEGIN("fmi2GetIntegerStatus", ANY) (void)s; (void)v; return no_status(c);
}
fmi2Status fmi2GetBooleanStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Boolean *v) {
    BEGIN("fmi2GetBooleanStatus", ANY)
    if (s == fmi2Terminated) { *v = fmi2False; return fmi2OK; }
    return no_status(c);
}
fmi2Status fmi2GetStringStatus(fmi2Component comp, const fmi2StatusKind s, fmi2String *v) {
    BEGIN("fmi2GetStringStatus", ANY) (void)s; (void)v; return no_status(c);
}

/* -------------------------------------------------------------- FMU state
 * A state is one array of doubles: a header, every variable, the model's
 * whole memory (fractional history, hysteretic state, solver state). */

typedef struct { size_t n; double d[1]; } Blob;

/* the signal FMU offers no FMU state (its model description says so): its
 * table belongs to a file name the state would not carry */
#if MODEL_KIND == KIND_SIGNAL
#define NO_STATE(c)                                                                              \
    do {                                                                                         \
        fonbw_log(c, fmi2Error, "logStatusError", "FMU states are not supported by this FMU");   \
        return fmi2Error;                                                                        \
    } while (0)
#else
#define NO_STATE(c) (void)0
#endif

enum { H_MAGIC, H_KIND, H_PHASE, H_TIME, H_ENGINE, H_BUILT, H_BAD, H_NMODEL, H_SIZE };

static size_t blob_len(const Instance *c) { return H_SIZE + 2 * NVR + inst_model_size(c); }

static void blob_write(const Instance *c, double *d) {
    size_t nm = inst_model_size(c);
    int k;
    d[H_MAGIC] = STATE_MAGIC; d[H_KIND] = MODEL_KIND; d[H_PHASE] = c->phase; d[H_TIME] = c->time;
    d[H_ENGINE] = c->engine; d[H_BUILT] = c->built; d[H_BAD] = c->bad_before; d[H_NMODEL] = (double)nm;
    for (k = 0; k < NVR; k++) { d[H_SIZE + k] = c->r[k]; d[H_SIZE + NVR + k] = c->i[k]; }
    if (nm) inst_model_write(c, d + H_SIZE + 2 * NVR);
}

static fmi2Status blob_read(Instance *c, const double *d, size_t n) {
    size_t nm;
    int k, rc = 0;
    if (n < H_SIZE + 2 * NVR || d[H_MAGIC] != STATE_MAGIC || d[H_KIND] != MODEL_KIND ||
        (nm = (size_t)d[H_NMODEL]) != n - H_SIZE - 2 * NVR || d[H_ENGINE] < 0 || d[H_ENGINE] > 2) {
        fonbw_log(c, fmi2Error, "logStatusError", "the FMU state does not belong to this FMU");
        return fmi2Error;
    }
    for (k = 0; k < NVR; k++) { c->r[k] = d[H_SIZE + k]; c->i[k] = (int)d[H_SIZE + NVR + k]; }
    if (MODEL_KIND == KIND_PID && (c->i[VR_INTEGRATOR] < 0 || c->i[VR_INTEGRATOR] > 2 ||
                                   c->i[VR_ANTI_WINDUP] < 0 || c->i[VR_ANTI_WINDUP] > 2)) {
        fonbw_log(c, fmi2Error, "logStatusError", "the FMU state does not belong to this FMU");
        c->phase = ST_ERROR;
        return fmi2Error;
    }
    c->engine = (int)d[H_ENGINE];
    c->phase = (Phase)(int)d[H_PHASE];
    c->time = d[H_TIME];
    c->bad_before = (int)d[H_BAD];
    if (d[H_BUILT] == 0.0) { inst_free_model(c); return fmi2OK; }
    if ((!c->built || inst_params_changed(c)) && inst_build_model(c) != 0) { c->phase = ST_ERROR; return fmi2Error; }
    rc = inst_model_read(c, d + H_SIZE + 2 * NVR, nm);
    if (rc != 0) {
        fonbw_log(c, fmi2Error, "logStatusError", "the FMU state does not fit this instance's model");
        return fmi2Error;
    }
    return fmi2OK;
}

fmi2Status fmi2GetFMUstate(fmi2Component comp, fmi2FMUstate *state) {
    size_t n;
    Blob *b;
    BEGIN("fmi2GetFMUstate", ANY & ~ST_ERROR)
    NO_STATE(c);
    n = blob_len(c);
    b = (Blob *)*state;
    if (!b || b->n != n) {
        free(b);
        b = malloc(sizeof(Blob) + sizeof(double) * n);
        if (!b) { *state = NULL; fonbw_log(c, fmi2Error, "logStatusError", "out of memory"); return fmi2Error; }
        b->n = n;
    }
    blob_write(c, b->d);
    *state = b;
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component comp, fmi2FMUstate state) {
    const Blob *b = (const Blob *)state;
    BEGIN("fmi2SetFMUstate", ANY & ~ST_ERROR)
    NO_STATE(c);
    if (!b) return fmi2Error;
    return blob_read(c, b->d, b->n);
}

fmi2Status fmi2FreeFMUstate(fmi2Component comp, fmi2FMUstate *state) {
    BEGIN("fmi2FreeFMUstate", ANY)
    if (state) { free(*state); *state = NULL; }
    return fmi2OK;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component comp, fmi2FMUstate state, size_t *size) {
    const Blob *b = (const Blob *)state;
    BEGIN("fmi2SerializedFMUstateSize", ANY)
    NO_STATE(c);
    if (!b) return fmi2Error;
    *size = sizeof(double) * (1 + b->n);
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component comp, fmi2FMUstate state, fmi2Byte bytes[], size_t size) {
    const Blob *b = (const Blob *)state;
    double n;
    BEGIN("fmi2SerializeFMUstate", ANY)
    NO_STATE(c);
    if (!b || size < sizeof(double) * (1 + b->n)) return fmi2Error;
    n = (double)b->n;
    memcpy(bytes, &n, sizeof n);
    memcpy(bytes + sizeof n, b->d, sizeof(double) * b->n);
    return fmi2OK;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component comp, const fmi2Byte bytes[], size_t size, fmi2FMUstate *state) {
    double n;
    Blob *b;
    BEGIN("fmi2DeSerializeFMUstate", ANY)
    NO_STATE(c);
    if (size < sizeof n) return fmi2Error;
    memcpy(&n, bytes, sizeof n);
    if (n < H_SIZE || n > 1e12 || size != sizeof(double) * (1 + (size_t)n)) {
        fonbw_log(c, fmi2Error, "logStatusError", "serialized FMU state of the wrong size");
        return fmi2Error;
    }
    b = malloc(sizeof(Blob) + sizeof(double) * (size_t)n);
    if (!b) return fmi2Error;
    b->n = (size_t)n;
    memcpy(b->d, bytes + sizeof n, sizeof(double) * b->n);
    if (b->d[H_MAGIC] != STATE_MAGIC || b->d[H_KIND] != MODEL_KIND) {
        free(b);
        fonbw_log(c, fmi2Error, "logStatusError", "the serialized FMU state does not belong to this FMU");
        return fmi2Error;
    }
    free(*state);
    *state = b;
    return fmi2OK;
}
