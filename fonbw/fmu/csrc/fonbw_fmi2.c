/* FMI 2.0 co-simulation interface of the fonbw native FMUs.
 *
 * One source for the three FMUs; config.h (written by the builder into each
 * FMU's sources/) selects the model and holds the build-time start values:
 *   MODEL_KIND 1  FonbwHysteresisNative   u [V]     -> y [um]
 *   MODEL_KIND 2  FonbwCompensatorNative  y_ref [um] -> u [V], status
 *   MODEL_KIND 3  FonbwLinearPlantNative  input -> output (state space)
 *   MODEL_KIND 4  FonbwPIDNative          r, y [um], u_ff [V] -> u [V]
 * With PASS_THROUGH defined, the FMU keeps the variables, parameters and
 * checks of its kind but its step is output = first input (a baseline that
 * shows what a master spends around the model).
 * Numerics in fonbw_numerics.c, fonbw_compensator.c, fonbw_plant.c,
 * fonbw_pid.c. Every entry point checks the instance and its state in one
 * place (BEGIN). */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "config.h"
#include "fmi2Functions.h"
#include "fonbw_numerics.h"

#define KIND_HYST 1
#define KIND_COMP 2
#define KIND_PLANT 3
#define KIND_PID 4
#ifndef PASS_THROUGH
#define PASS_THROUGH 0
#endif

/* value references (Real, Integer and String share one numbering) */
enum { VR_IN = 0, VR_OUT = 1, VR_KH = 2, VR_RHO = 3, VR_SIGMA = 4, VR_N = 5, VR_LAM1 = 6,
       VR_LAM2 = 7, VR_DT = 8, VR_UMIN = 9, VR_UMAX = 10, VR_Y = 11, VR_UFF = 12, VR_KP = 13,
       VR_KI = 14, VR_KD = 15, VR_TF = 16, VR_TT = 17, VR_KU = 20,
       VR_K = 40, VR_M = 41, VR_L = 42, VR_STATUS = 43, VR_MEMORY = 50, VR_INTEGRATOR = 51,
       VR_ANTI_WINDUP = 52, NVR = 53 };

#define STEP_MULTIPLE_TOL 1e-6
#define STATE_MAGIC 4607863412.0

typedef enum { ST_INSTANTIATED = 1, ST_INIT = 2, ST_STEP = 4, ST_TERMINATED = 8, ST_ERROR = 16 } Phase;
#define ANY (ST_INSTANTIATED | ST_INIT | ST_STEP | ST_TERMINATED | ST_ERROR)

typedef struct {
    char *name;
    fmi2CallbackFunctions cb;
    int logging;
    Phase phase;
    double time;
    double r[NVR];          /* Real variables by value reference */
    int i[NVR];             /* Integer variables by value reference */
    int engine;             /* the String parameter memory */
    int built;              /* the model below exists */
    double built_from[NVR]; /* parameters it was built from */
    int built_from_i[NVR];
    int built_engine;
    Fonbw hyst;
    Compensator comp;
    Plant plant;
    Pid pid;
    int bad_before;         /* compensator: in a saturation episode */
} Instance;

static const char *ENGINE_NAMES[] = {"fast", "exact", "short"};
static const char *INTEGRATOR_NAMES[] = {"forward", "backward", "tustin"};
static const char *ANTI_WINDUP_NAMES[] = {"back-calculation", "clamping", "none"};

static void logf_(Instance *c, fmi2Status st, const char *cat, const char *fmt, ...) {
    char buf[1024];
    va_list ap;
    if (!c->cb.logger || (st == fmi2OK && !c->logging)) return;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    c->cb.logger(c->cb.componentEnvironment, c->name, st, cat, "%s", buf);
}

/* one place for the instance and state checks of every entry point */
#define BEGIN(fn, allowed)                                                            \
    Instance *c = (Instance *)comp;                                                   \
    if (!c) return fmi2Error;                                                         \
    if (!(c->phase & (allowed))) {                                                    \
        logf_(c, fmi2Error, "logStatusError", fn " is not allowed in this state");    \
        return fmi2Error;                                                             \
    }

static int is_input(int vr) {
    return vr == VR_IN || (MODEL_KIND == KIND_PID && (vr == VR_Y || vr == VR_UFF));
}

static int is_param(int vr) {
    if (vr == VR_DT) return 1;
#if MODEL_KIND == KIND_PID
    if (vr == VR_UMIN || vr == VR_UMAX || (vr >= VR_KP && vr <= VR_TT) || vr == VR_INTEGRATOR ||
        vr == VR_ANTI_WINDUP) return 1;
#elif MODEL_KIND != KIND_PLANT
    if ((vr >= VR_KH && vr <= VR_LAM2) || (vr >= VR_KU && vr < VR_KU + NKU) ||
        vr == VR_K || vr == VR_M || vr == VR_L || vr == VR_MEMORY) return 1;
#if MODEL_KIND == KIND_COMP
    if (vr == VR_UMIN || vr == VR_UMAX) return 1;
#endif
#endif
    return 0;
}

static int is_real(int vr) {
    return is_input(vr) || vr == VR_OUT || (is_param(vr) && vr < VR_K);
}

static int is_int(int vr) {
#if MODEL_KIND == KIND_COMP
    if (vr == VR_STATUS) return 1;
#endif
    return MODEL_KIND != KIND_PLANT && MODEL_KIND != KIND_PID && (vr == VR_K || vr == VR_M || vr == VR_L);
}

/* the names a String parameter takes (NULL: not a String variable), and where its index is kept */
static const char **string_names(Instance *c, int vr, int *count, int **slot) {
    if (MODEL_KIND == KIND_PID && (vr == VR_INTEGRATOR || vr == VR_ANTI_WINDUP)) {
        *count = 3;
        *slot = &c->i[vr];
        return vr == VR_INTEGRATOR ? INTEGRATOR_NAMES : ANTI_WINDUP_NAMES;
    }
    if (MODEL_KIND != KIND_PLANT && MODEL_KIND != KIND_PID && vr == VR_MEMORY) {
        *count = 3;
        *slot = &c->engine;
        return ENGINE_NAMES;
    }
    return NULL;
}

static void set_defaults(Instance *c) {
    memset(c->r, 0, sizeof c->r);
    memset(c->i, 0, sizeof c->i);
    c->r[VR_DT] = DEFAULT_DT;
#if MODEL_KIND == KIND_PID
    c->r[VR_KP] = DEFAULT_KP; c->r[VR_KI] = DEFAULT_KI; c->r[VR_KD] = DEFAULT_KD;
    c->r[VR_TF] = DEFAULT_TF; c->r[VR_TT] = DEFAULT_TT;
    c->r[VR_UMIN] = DEFAULT_UMIN; c->r[VR_UMAX] = DEFAULT_UMAX;
    c->i[VR_INTEGRATOR] = DEFAULT_INTEGRATOR; c->i[VR_ANTI_WINDUP] = DEFAULT_ANTI_WINDUP;
#elif MODEL_KIND != KIND_PLANT
    {
        static const double ku[NKU] = DEFAULT_KU;
        int k;
        for (k = 0; k < NKU; k++) c->r[VR_KU + k] = ku[k];
    }
    c->r[VR_KH] = DEFAULT_KH; c->r[VR_RHO] = DEFAULT_RHO; c->r[VR_SIGMA] = DEFAULT_SIGMA;
    c->r[VR_N] = DEFAULT_N; c->r[VR_LAM1] = DEFAULT_LAM1; c->r[VR_LAM2] = DEFAULT_LAM2;
    c->r[VR_UMIN] = DEFAULT_UMIN; c->r[VR_UMAX] = DEFAULT_UMAX;
    c->i[VR_K] = DEFAULT_K; c->i[VR_M] = DEFAULT_M; c->i[VR_L] = DEFAULT_L;
    c->engine = DEFAULT_ENGINE;
#endif
}

static void free_model(Instance *c) {
    if (!c->built) return;
#if PASS_THROUGH
#elif MODEL_KIND == KIND_HYST
    fonbw_free(&c->hyst);
#elif MODEL_KIND == KIND_COMP
    comp_free(&c->comp);
#endif
    c->built = 0;
}

#if MODEL_KIND != KIND_PLANT && MODEL_KIND != KIND_PID
static FonbwParams params_of(const Instance *c) {
    FonbwParams p;
    int k;
    memset(&p, 0, sizeof p);
    p.N = NKU;
    for (k = 0; k < NKU; k++) p.ku[k] = c->r[VR_KU + k];
    p.kh = c->r[VR_KH]; p.rho = c->r[VR_RHO]; p.sigma = c->r[VR_SIGMA]; p.n = c->r[VR_N];
    p.lam1 = c->r[VR_LAM1]; p.lam2 = c->r[VR_LAM2];
    p.engine = c->engine; p.K = c->i[VR_K]; p.M = c->i[VR_M]; p.L = c->i[VR_L];
    return p;
}
#endif

/* build the model from the parameters: 0, or -1 with an fmi2Error log line */
static int build_model(Instance *c) {
    char msg[256];
    const char *bad = NULL;
    double dt = c->r[VR_DT];
    int rc = 0;
    free_model(c);
#if PASS_THROUGH
    (void)rc;
    if (!(isfinite(dt) && dt > 0.0)) {
        snprintf(msg, sizeof msg, "dt = %.17g s must be a finite number > 0", dt);
        bad = msg;
    }
#elif MODEL_KIND == KIND_PID
    {
        Pid *p = &c->pid;
        memset(p, 0, sizeof *p);
        p->kp = c->r[VR_KP]; p->ki = c->r[VR_KI]; p->kd = c->r[VR_KD]; p->dt = dt;
        p->lo = c->r[VR_UMIN]; p->hi = c->r[VR_UMAX]; p->Tf = c->r[VR_TF]; p->Tt = c->r[VR_TT];
        p->integrator = c->i[VR_INTEGRATOR]; p->anti_windup = c->i[VR_ANTI_WINDUP];
        bad = pid_check(p, msg, sizeof msg);
    }
#elif MODEL_KIND == KIND_PLANT
    {
        static const double A[] = PLANT_A, B[] = PLANT_B, C[] = PLANT_C;
        memset(&c->plant, 0, sizeof c->plant);
        c->plant.n = NSTATES;
        c->plant.D = PLANT_D;
        memcpy(c->plant.C, C, sizeof C);
        if (!(isfinite(dt) && dt > 0.0)) {
            snprintf(msg, sizeof msg, "dt = %.17g s must be a finite number > 0", dt);
            bad = msg;
        } else if (PLANT_DT > 0.0) {
            if (fabs(dt - PLANT_DT) > 1e-12 * PLANT_DT) {
                snprintf(msg, sizeof msg, "dt = %.17g s differs from the sampling time %.17g s of the "
                         "discrete-time plant", dt, (double)PLANT_DT);
                bad = msg;
            } else {
                memcpy(c->plant.A, A, sizeof A);
                memcpy(c->plant.B, B, sizeof B);
            }
        } else if (plant_c2d(NSTATES, A, B, dt, c->plant.A, c->plant.B) != 0) {
            snprintf(msg, sizeof msg, "the plant cannot be discretized with dt = %.17g s", dt);
            bad = msg;
        }
    }
#else
    {
        FonbwParams p = params_of(c);
        bad = fonbw_check(&p, dt, msg, sizeof msg);
#if MODEL_KIND == KIND_COMP
        if (!bad && !(isfinite(c->r[VR_UMIN]) && isfinite(c->r[VR_UMAX]) && c->r[VR_UMIN] < c->r[VR_UMAX])) {
            snprintf(msg, sizeof msg, "u_min = %.17g V and u_max = %.17g V must be finite with u_min < u_max",
                     c->r[VR_UMIN], c->r[VR_UMAX]);
            bad = msg;
        }
        if (!bad) rc = comp_init(&c->comp, &p, dt, c->r[VR_UMIN], c->r[VR_UMAX]);
#else
        if (!bad) rc = fonbw_init(&c->hyst, &p, dt);
#endif
    }
#endif
    if (bad || rc != 0) {
        logf_(c, fmi2Error, "logStatusError", "invalid parameters: %s", bad ? bad : "out of memory");
        return -1;
    }
    c->built = 1;
    memcpy(c->built_from, c->r, sizeof c->r);
    memcpy(c->built_from_i, c->i, sizeof c->i);
    c->built_engine = c->engine;
    return 0;
}

static int params_changed(const Instance *c) {
    int vr;
    for (vr = 0; vr < NVR; vr++) {
        if (!is_param(vr)) continue;
        if (is_real(vr) ? memcmp(&c->r[vr], &c->built_from[vr], sizeof(double)) != 0
                        : c->i[vr] != c->built_from_i[vr]) return 1;
    }
    return c->engine != c->built_engine;
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
        logf_(c, fmi2Error, "logStatusError", type != fmi2CoSimulation
              ? "only co-simulation is supported" : "the GUID does not match this FMU");
        free(c->name); free(c);
        return NULL;
    }
    c->phase = ST_INSTANTIATED;
    set_defaults(c);
    return c;
}

void fmi2FreeInstance(fmi2Component comp) {
    Instance *c = (Instance *)comp;
    if (!c) return;
    free_model(c);
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
    c->phase = ST_INIT;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component comp) {
    BEGIN("fmi2ExitInitializationMode", ST_INIT)
    if (build_model(c) != 0) { c->phase = ST_ERROR; return fmi2Error; }
    c->r[VR_OUT] = 0.0;
    c->i[VR_STATUS] = 0;
    c->bad_before = 0;
#if MODEL_KIND == KIND_COMP && !PASS_THROUGH
    {
        double slope = c->r[VR_KU] + c->r[VR_KH] * c->r[VR_RHO] * pow(c->r[VR_DT], c->r[VR_LAM2] - c->r[VR_LAM1]);
        if (!(slope > 0.0))
            logf_(c, fmi2Warning, "logStatusWarning", "the model is not invertible at this step: its "
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
    free_model(c);
    set_defaults(c);
    c->time = 0.0;
    c->phase = ST_INSTANTIATED;
    return fmi2OK;
}

/* ------------------------------------------------------------- variables */

static double output(const Instance *c) {
#if MODEL_KIND == KIND_PLANT && !PASS_THROUGH
    return c->built ? plant_output(&c->plant, c->r[VR_IN]) : 0.0;
#else
    return c->r[VR_OUT];
#endif
}

static fmi2Status bad_vr(Instance *c, const char *fn, fmi2ValueReference vr) {
    logf_(c, fmi2Error, "logStatusError", "%s: unknown value reference %u", fn, (unsigned)vr);
    return fmi2Error;
}

/* a parameter may change until initialization ends (fixed variability) */
static fmi2Status may_set(Instance *c, const char *fn, fmi2ValueReference vr) {
    if (is_input((int)vr)) return fmi2OK;
    if (!is_param((int)vr)) {
        logf_(c, fmi2Error, "logStatusError", "%s: value reference %u is not an input or parameter",
              fn, (unsigned)vr);
        return fmi2Error;
    }
    if (!(c->phase & (ST_INSTANTIATED | ST_INIT))) {
        logf_(c, fmi2Error, "logStatusError", "%s: value reference %u is a fixed parameter, "
              "settable only before fmi2ExitInitializationMode", fn, (unsigned)vr);
        return fmi2Error;
    }
    return fmi2OK;
}

fmi2Status fmi2GetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t n, fmi2Real v[]) {
    size_t k;
    BEGIN("fmi2GetReal", ANY & ~ST_ERROR)
    for (k = 0; k < n; k++) {
        if (vr[k] >= NVR || !is_real((int)vr[k])) return bad_vr(c, "fmi2GetReal", vr[k]);
        v[k] = vr[k] == VR_OUT ? output(c) : c->r[vr[k]];
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t n, const fmi2Real v[]) {
    size_t k;
    BEGIN("fmi2SetReal", ST_INSTANTIATED | ST_INIT | ST_STEP)
    for (k = 0; k < n; k++) {
        if (vr[k] >= NVR || !is_real((int)vr[k])) return bad_vr(c, "fmi2SetReal", vr[k]);
        if (may_set(c, "fmi2SetReal", vr[k]) != fmi2OK) return fmi2Error;
        c->r[vr[k]] = v[k];
    }
    return fmi2OK;
}

fmi2Status fmi2GetInteger(fmi2Component comp, const fmi2ValueReference vr[], size_t n, fmi2Integer v[]) {
    size_t k;
    BEGIN("fmi2GetInteger", ANY & ~ST_ERROR)
    for (k = 0; k < n; k++) {
        if (vr[k] >= NVR || !is_int((int)vr[k])) return bad_vr(c, "fmi2GetInteger", vr[k]);
        v[k] = c->i[vr[k]];
    }
    return fmi2OK;
}

fmi2Status fmi2SetInteger(fmi2Component comp, const fmi2ValueReference vr[], size_t n, const fmi2Integer v[]) {
    size_t k;
    BEGIN("fmi2SetInteger", ST_INSTANTIATED | ST_INIT | ST_STEP)
    for (k = 0; k < n; k++) {
        if (vr[k] >= NVR || !is_int((int)vr[k])) return bad_vr(c, "fmi2SetInteger", vr[k]);
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
    BEGIN("fmi2GetString", ANY & ~ST_ERROR)
    for (k = 0; k < n; k++) {
        if (vr[k] >= NVR || !(names = string_names(c, (int)vr[k], &count, &slot)))
            return bad_vr(c, "fmi2GetString", vr[k]);
        v[k] = names[*slot];
    }
    return fmi2OK;
}

fmi2Status fmi2SetString(fmi2Component comp, const fmi2ValueReference vr[], size_t n, const fmi2String v[]) {
    size_t k;
    int e, count, *slot;
    const char **names;
    BEGIN("fmi2SetString", ST_INSTANTIATED | ST_INIT | ST_STEP)
    for (k = 0; k < n; k++) {
        if (vr[k] >= NVR || !(names = string_names(c, (int)vr[k], &count, &slot)))
            return bad_vr(c, "fmi2SetString", vr[k]);
        if (may_set(c, "fmi2SetString", vr[k]) != fmi2OK) return fmi2Error;
        for (e = 0; e < count; e++) if (v[k] && strcmp(v[k], names[e]) == 0) break;
        if (e == count) {
            logf_(c, fmi2Error, "logStatusError", "invalid parameters: '%s' is not one of %s, %s, %s%s",
                  v[k] ? v[k] : "(null)", names[0], names[1], names[2], vr[k] == VR_MEMORY
                  ? " (oustaloup is not available in the native FMUs)" : "");
            return fmi2Error;
        }
        *slot = e;
    }
    return fmi2OK;
}

/* ---------------------------------------------------------------- stepping */

static void one_step(Instance *c) {
#if PASS_THROUGH
    c->r[VR_OUT] = c->r[VR_IN];
#elif MODEL_KIND == KIND_PID
    c->r[VR_OUT] = pid_step(&c->pid, c->r[VR_IN], c->r[VR_Y], c->r[VR_UFF]);
#elif MODEL_KIND == KIND_HYST
    c->r[VR_OUT] = fonbw_step(&c->hyst, c->r[VR_IN], 1);
#elif MODEL_KIND == KIND_COMP
    c->r[VR_OUT] = comp_step(&c->comp, c->r[VR_IN]);
    c->i[VR_STATUS] = (int)c->comp.status;
#else
    plant_advance(&c->plant, c->r[VR_IN]);
#endif
}

fmi2Status fmi2DoStep(fmi2Component comp, fmi2Real t, fmi2Real h, fmi2Boolean noSetPrior) {
    double m;
    long k, j;
    BEGIN("fmi2DoStep", ST_STEP)
    (void)noSetPrior;
    m = h / c->r[VR_DT];
    k = (m >= 0.5 && m < 1e15) ? (long)(m + 0.5) : 0;
    if (k < 1 || fabs(m - (double)k) > STEP_MULTIPLE_TOL) {
        logf_(c, fmi2Discard, "logStatusDiscard", "doStep at t=%.17g refused: communication step %.17g s "
              "is not a whole multiple of the internal step dt = %.17g s (ratio %.17g); no resampling "
              "is done", t, h, c->r[VR_DT], m);
        return fmi2Discard;
    }
    if (!isfinite(c->r[VR_IN]) || (MODEL_KIND == KIND_PID && !(isfinite(c->r[VR_Y]) && isfinite(c->r[VR_UFF])))) {
        logf_(c, fmi2Discard, "logStatusDiscard", "doStep at t=%.17g refused: an input is not finite", t);
        return fmi2Discard;
    }
#if MODEL_KIND == KIND_COMP && !PASS_THROUGH
    {
        double bad0 = c->comp.n_sat + c->comp.n_fail;
        for (j = 0; j < k; j++) one_step(c);
        if (c->comp.n_sat + c->comp.n_fail > bad0) {
            if (!c->bad_before)
                logf_(c, fmi2Warning, "logStatusWarning", "at t=%.17g y_ref=%.17g um: %s (u = %.17g V); "
                      "further samples of this episode are not logged, see the status output", t,
                      c->r[VR_IN], c->comp.status == COMP_SAT_LOW ? "saturated at u_min" :
                      c->comp.status == COMP_SAT_HIGH ? "saturated at u_max" : "not converged",
                      c->r[VR_OUT]);
            c->bad_before = 1;
        } else c->bad_before = 0;
    }
#else
    for (j = 0; j < k; j++) one_step(c);
#endif
    c->time = t + h;
    return fmi2OK;
}

fmi2Status fmi2CancelStep(fmi2Component comp) {
    BEGIN("fmi2CancelStep", ST_STEP)
    logf_(c, fmi2Error, "logStatusError", "fmi2CancelStep: doStep always completes synchronously");
    return fmi2Error;
}

fmi2Status fmi2SetRealInputDerivatives(fmi2Component comp, const fmi2ValueReference vr[], size_t n,
                                       const fmi2Integer order[], const fmi2Real v[]) {
    BEGIN("fmi2SetRealInputDerivatives", ANY)
    (void)vr; (void)n; (void)order; (void)v;
    logf_(c, fmi2Error, "logStatusError", "input derivatives are not supported");
    return fmi2Error;
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component comp, const fmi2ValueReference vr[], size_t n,
                                        const fmi2Integer order[], fmi2Real v[]) {
    BEGIN("fmi2GetRealOutputDerivatives", ANY)
    (void)vr; (void)n; (void)order; (void)v;
    logf_(c, fmi2Error, "logStatusError", "output derivatives are not supported");
    return fmi2Error;
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component comp, const fmi2ValueReference u[], size_t nu,
                                        const fmi2ValueReference z[], size_t nz, const fmi2Real du[],
                                        fmi2Real dz[]) {
    BEGIN("fmi2GetDirectionalDerivative", ANY)
    (void)u; (void)nu; (void)z; (void)nz; (void)du; (void)dz;
    logf_(c, fmi2Error, "logStatusError", "directional derivatives are not supported");
    return fmi2Error;
}

static fmi2Status no_status(Instance *c) {
    logf_(c, fmi2Error, "logStatusError", "doStep is synchronous: there is no pending status");
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

enum { H_MAGIC, H_KIND, H_PHASE, H_TIME, H_ENGINE, H_BUILT, H_BAD, H_NMODEL, H_SIZE };

static size_t model_size(const Instance *c) {
    if (!c->built) return 0;
#if PASS_THROUGH
    return 0;
#elif MODEL_KIND == KIND_PID
    return 3;
#elif MODEL_KIND == KIND_HYST
    return fonbw_state_size(&c->hyst);
#elif MODEL_KIND == KIND_COMP
    return comp_state_size(&c->comp);
#else
    return (size_t)c->plant.n;
#endif
}

static size_t blob_len(const Instance *c) { return H_SIZE + 2 * NVR + model_size(c); }

static void blob_write(const Instance *c, double *d) {
    size_t nm = model_size(c);
    int k;
    d[H_MAGIC] = STATE_MAGIC; d[H_KIND] = MODEL_KIND; d[H_PHASE] = c->phase; d[H_TIME] = c->time;
    d[H_ENGINE] = c->engine; d[H_BUILT] = c->built; d[H_BAD] = c->bad_before; d[H_NMODEL] = (double)nm;
    for (k = 0; k < NVR; k++) { d[H_SIZE + k] = c->r[k]; d[H_SIZE + NVR + k] = c->i[k]; }
    if (!nm) return;
#if PASS_THROUGH
#elif MODEL_KIND == KIND_PID
    d += H_SIZE + 2 * NVR;
    d[0] = c->pid.i; d[1] = c->pid.e1; d[2] = c->pid.d1;
#elif MODEL_KIND == KIND_HYST
    fonbw_state_write(&c->hyst, d + H_SIZE + 2 * NVR);
#elif MODEL_KIND == KIND_COMP
    comp_state_write(&c->comp, d + H_SIZE + 2 * NVR);
#else
    memcpy(d + H_SIZE + 2 * NVR, c->plant.x, sizeof(double) * nm);
#endif
}

static fmi2Status blob_read(Instance *c, const double *d, size_t n) {
    size_t nm;
    int k, rc = 0;
    if (n < H_SIZE + 2 * NVR || d[H_MAGIC] != STATE_MAGIC || d[H_KIND] != MODEL_KIND ||
        (nm = (size_t)d[H_NMODEL]) != n - H_SIZE - 2 * NVR || d[H_ENGINE] < 0 || d[H_ENGINE] > 2) {
        logf_(c, fmi2Error, "logStatusError", "the FMU state does not belong to this FMU");
        return fmi2Error;
    }
    for (k = 0; k < NVR; k++) { c->r[k] = d[H_SIZE + k]; c->i[k] = (int)d[H_SIZE + NVR + k]; }
    if (MODEL_KIND == KIND_PID && (c->i[VR_INTEGRATOR] < 0 || c->i[VR_INTEGRATOR] > 2 ||
                                   c->i[VR_ANTI_WINDUP] < 0 || c->i[VR_ANTI_WINDUP] > 2)) {
        logf_(c, fmi2Error, "logStatusError", "the FMU state does not belong to this FMU");
        c->phase = ST_ERROR;
        return fmi2Error;
    }
    c->engine = (int)d[H_ENGINE];
    c->phase = (Phase)(int)d[H_PHASE];
    c->time = d[H_TIME];
    c->bad_before = (int)d[H_BAD];
    if (d[H_BUILT] == 0.0) { free_model(c); return fmi2OK; }
    if ((!c->built || params_changed(c)) && build_model(c) != 0) { c->phase = ST_ERROR; return fmi2Error; }
    d += H_SIZE + 2 * NVR;
#if PASS_THROUGH
    if (nm != 0) rc = -1;
#elif MODEL_KIND == KIND_PID
    if (nm != 3) rc = -1; else { c->pid.i = d[0]; c->pid.e1 = d[1]; c->pid.d1 = d[2]; }
#elif MODEL_KIND == KIND_HYST
    rc = fonbw_state_read(&c->hyst, d, nm);
#elif MODEL_KIND == KIND_COMP
    rc = comp_state_read(&c->comp, d, nm);
#else
    if (nm != (size_t)c->plant.n) rc = -1; else memcpy(c->plant.x, d, sizeof(double) * nm);
#endif
    if (rc != 0) {
        logf_(c, fmi2Error, "logStatusError", "the FMU state does not fit this instance's model");
        return fmi2Error;
    }
    return fmi2OK;
}

fmi2Status fmi2GetFMUstate(fmi2Component comp, fmi2FMUstate *state) {
    size_t n;
    Blob *b;
    BEGIN("fmi2GetFMUstate", ANY & ~ST_ERROR)
    n = blob_len(c);
    b = (Blob *)*state;
    if (!b || b->n != n) {
        free(b);
        b = malloc(sizeof(Blob) + sizeof(double) * n);
        if (!b) { *state = NULL; logf_(c, fmi2Error, "logStatusError", "out of memory"); return fmi2Error; }
        b->n = n;
    }
    blob_write(c, b->d);
    *state = b;
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component comp, fmi2FMUstate state) {
    const Blob *b = (const Blob *)state;
    BEGIN("fmi2SetFMUstate", ANY & ~ST_ERROR)
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
    if (!b) return fmi2Error;
    *size = sizeof(double) * (1 + b->n);
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component comp, fmi2FMUstate state, fmi2Byte bytes[], size_t size) {
    const Blob *b = (const Blob *)state;
    double n;
    BEGIN("fmi2SerializeFMUstate", ANY)
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
    if (size < sizeof n) return fmi2Error;
    memcpy(&n, bytes, sizeof n);
    if (n < H_SIZE || n > 1e12 || size != sizeof(double) * (1 + (size_t)n)) {
        logf_(c, fmi2Error, "logStatusError", "serialized FMU state of the wrong size");
        return fmi2Error;
    }
    b = malloc(sizeof(Blob) + sizeof(double) * (size_t)n);
    if (!b) return fmi2Error;
    b->n = (size_t)n;
    memcpy(b->d, bytes + sizeof n, sizeof(double) * b->n);
    if (b->d[H_MAGIC] != STATE_MAGIC || b->d[H_KIND] != MODEL_KIND) {
        free(b);
        logf_(c, fmi2Error, "logStatusError", "the serialized FMU state does not belong to this FMU");
        return fmi2Error;
    }
    free(*state);
    *state = b;
    return fmi2OK;
}
