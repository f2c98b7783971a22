/* The per-model parts of the fonbw native FMUs (see fonbw_instance.h): the
 * variables of each kind, its build-time start values, building the model
 * from the parameters at initialization (with the parameter checks), the
 * internal steps, and the model's own part of the FMU state. Numerics in
 * fonbw_numerics.c, fonbw_compensator.c, fonbw_plant.c, fonbw_pid.c; the
 * signal's table in fonbw_table.c. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fonbw_instance.h"

static const char *ENGINE_NAMES[] = {"fast", "exact", "short"};
static const char *INTEGRATOR_NAMES[] = {"forward", "backward", "tustin"};
static const char *ANTI_WINDUP_NAMES[] = {"back-calculation", "clamping", "none"};

int inst_is_input(int vr) {
    if (MODEL_KIND == KIND_SIGNAL) return 0;
    return vr == VR_IN || (MODEL_KIND == KIND_PID && (vr == VR_Y || vr == VR_UFF));
}

int inst_is_param(int vr) {
    if (vr == VR_DT) return 1;
#if MODEL_KIND == KIND_PID
    if (vr == VR_UMIN || vr == VR_UMAX || (vr >= VR_KP && vr <= VR_TT) || vr == VR_INTEGRATOR ||
        vr == VR_ANTI_WINDUP) return 1;
#elif MODEL_KIND == KIND_SIGNAL
    if (vr == VR_FILE) return 1;
#elif HAS_FONBW
    if ((vr >= VR_KH && vr <= VR_LAM2) || (vr >= VR_KU && vr < VR_KU + NKU) ||
        vr == VR_K || vr == VR_M || vr == VR_L || vr == VR_MEMORY ||
        (vr >= VR_REST_LO && vr <= VR_REST_T)) return 1;
#if MODEL_KIND == KIND_COMP
    if (vr == VR_UMIN || vr == VR_UMAX) return 1;
#endif
#endif
    return 0;
}

int inst_is_real(int vr) {
    return inst_is_input(vr) || vr == VR_OUT ||
           (inst_is_param(vr) && (vr < VR_K || (vr >= VR_REST_LO && vr <= VR_REST_T)));
}

int inst_is_int(int vr) {
#if MODEL_KIND == KIND_COMP
    if (vr == VR_STATUS) return 1;
#endif
    return HAS_FONBW && (vr == VR_K || vr == VR_M || vr == VR_L);
}

/* the names a String parameter takes (NULL: not an enumerated String), and where its index is kept */
const char **inst_string_names(Instance *c, int vr, int *count, int **slot) {
    if (MODEL_KIND == KIND_PID && (vr == VR_INTEGRATOR || vr == VR_ANTI_WINDUP)) {
        *count = 3;
        *slot = &c->i[vr];
        return vr == VR_INTEGRATOR ? INTEGRATOR_NAMES : ANTI_WINDUP_NAMES;
    }
    if (HAS_FONBW && vr == VR_MEMORY) {
        *count = 3;
        *slot = &c->engine;
        return ENGINE_NAMES;
    }
    return NULL;
}

char **inst_text(Instance *c, int vr) {
    return MODEL_KIND == KIND_SIGNAL && vr == VR_FILE ? &c->file : NULL;
}

void inst_set_defaults(Instance *c) {
    memset(c->r, 0, sizeof c->r);
    memset(c->i, 0, sizeof c->i);
    c->r[VR_DT] = DEFAULT_DT;
#if MODEL_KIND == KIND_PID
    c->r[VR_KP] = DEFAULT_KP; c->r[VR_KI] = DEFAULT_KI; c->r[VR_KD] = DEFAULT_KD;
    c->r[VR_TF] = DEFAULT_TF; c->r[VR_TT] = DEFAULT_TT;
    c->r[VR_UMIN] = DEFAULT_UMIN; c->r[VR_UMAX] = DEFAULT_UMAX;
    c->i[VR_INTEGRATOR] = DEFAULT_INTEGRATOR; c->i[VR_ANTI_WINDUP] = DEFAULT_ANTI_WINDUP;
#elif HAS_FONBW
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
    {
        static const double rest[3] = REST_CYCLE;  /* the model's recorded start */
        c->r[VR_REST_LO] = rest[0]; c->r[VR_REST_HI] = rest[1]; c->r[VR_REST_T] = rest[2];
    }
#endif
}

void inst_free_model(Instance *c) {
    if (!c->built) return;
#if PASS_THROUGH
#elif MODEL_KIND == KIND_SIGNAL
    c->k_table = 0;  /* the table belongs to the file parameter, not to the built model */
#elif MODEL_KIND == KIND_HYST
    fonbw_free(&c->hyst);
#elif MODEL_KIND == KIND_COMP
    comp_free(&c->comp);
#endif
    c->built = 0;
}

void inst_release(Instance *c) {
    inst_free_model(c);
#if MODEL_KIND == KIND_SIGNAL
    table_drop(c);
#endif
    free(c->file);
    c->file = NULL;
}

int inst_enter_init(Instance *c) {
#if MODEL_KIND == KIND_SIGNAL && !PASS_THROUGH
    /* read now so that the initial output is known during initialization */
    c->k_table = 0;
    if (c->file && *c->file && table_load(c) != 0) return -1;
#else
    (void)c;
#endif
    return 0;
}

#if HAS_FONBW
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
int inst_build_model(Instance *c) {
    char msg[256];
    const char *bad = NULL;
    double dt = c->r[VR_DT];
    int rc = 0;
    inst_free_model(c);
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
#elif MODEL_KIND == KIND_SIGNAL
    if (!(isfinite(dt) && dt > 0.0)) {
        snprintf(msg, sizeof msg, "dt = %.17g s must be a finite number > 0", dt);
        bad = msg;
    } else if (!c->loaded_from || strcmp(c->loaded_from, c->file ? c->file : "") != 0) {
        /* the file changed since initialization started: read it again */
        if (table_load(c) != 0) return -1;
    }
    c->k_table = 0;
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
        /* the start: a rest cycle {lo, hi, T} run before t = 0, outputs counted from its end */
        const double rest[3] = {c->r[VR_REST_LO], c->r[VR_REST_HI], c->r[VR_REST_T]};
        bad = fonbw_check(&p, dt, msg, sizeof msg);
        if (!bad && !(isfinite(rest[2]) && rest[2] >= 0.0 &&
                      (rest[2] == 0.0 || (isfinite(rest[0]) && isfinite(rest[1]) && rest[0] < rest[1])))) {
            snprintf(msg, sizeof msg, "rest_T = %.17g s must be >= 0 (0: start from rest), and with a "
                     "rest cycle rest_lo = %.17g V < rest_hi = %.17g V", rest[2], rest[0], rest[1]);
            bad = msg;
        } else if (!bad && rest[2] / dt > REST_MAX_STEPS) {  /* a cycle run at initialization, not a hang */
            snprintf(msg, sizeof msg, "rest_T = %.17g s is more than %g steps of dt", rest[2],
                     (double)REST_MAX_STEPS);
            bad = msg;
        }
#if MODEL_KIND == KIND_COMP
        if (!bad && !(isfinite(c->r[VR_UMIN]) && isfinite(c->r[VR_UMAX]) && c->r[VR_UMIN] < c->r[VR_UMAX])) {
            snprintf(msg, sizeof msg, "u_min = %.17g V and u_max = %.17g V must be finite with u_min < u_max",
                     c->r[VR_UMIN], c->r[VR_UMAX]);
            bad = msg;
        }
        if (!bad) rc = comp_init(&c->comp, &p, dt, c->r[VR_UMIN], c->r[VR_UMAX], rest);
#else
        if (!bad) rc = fonbw_init(&c->hyst, &p, dt);
        c->hyst_y0 = 0.0;
        if (!bad && rc == 0 && fonbw_rest_samples(rest[2], dt) > 0)
            fonbw_rest_cycle(&c->hyst, rest[0], rest[1], fonbw_rest_samples(rest[2], dt), &c->hyst_y0);
#endif
    }
#endif
    if (bad || rc != 0) {
        fonbw_log(c, fmi2Error, "logStatusError", "invalid parameters: %s", bad ? bad : "out of memory");
        return -1;
    }
    c->built = 1;
    memcpy(c->built_from, c->r, sizeof c->r);
    memcpy(c->built_from_i, c->i, sizeof c->i);
    c->built_engine = c->engine;
    return 0;
}

int inst_params_changed(const Instance *c) {
    int vr;
    for (vr = 0; vr < NVR; vr++) {
        if (!inst_is_param(vr)) continue;
        if (inst_is_real(vr) ? memcmp(&c->r[vr], &c->built_from[vr], sizeof(double)) != 0
                        : c->i[vr] != c->built_from_i[vr]) return 1;
    }
    return c->engine != c->built_engine;
}

double inst_output(const Instance *c) {
#if MODEL_KIND == KIND_PLANT && !PASS_THROUGH
    return c->built ? plant_output(&c->plant, c->r[VR_IN]) : 0.0;
#elif MODEL_KIND == KIND_SIGNAL
    /* sample k after k internal steps, the last one held past the end */
    if (!c->n_table) return 0.0;
    return c->table[c->k_table < c->n_table ? c->k_table : c->n_table - 1];
#else
    return c->r[VR_OUT];
#endif
}

void inst_steps(Instance *c, long k) {
    long j;
#if MODEL_KIND == KIND_SIGNAL
    (void)j;
    c->k_table += (size_t)k;  /* a long communication step costs nothing */
#else
    for (j = 0; j < k; j++) {
#if PASS_THROUGH
        c->r[VR_OUT] = c->r[VR_IN];
#elif MODEL_KIND == KIND_PID
        c->r[VR_OUT] = pid_step(&c->pid, c->r[VR_IN], c->r[VR_Y], c->r[VR_UFF]);
#elif MODEL_KIND == KIND_HYST
        c->r[VR_OUT] = fonbw_step(&c->hyst, c->r[VR_IN], 1) - c->hyst_y0;
#elif MODEL_KIND == KIND_COMP
        c->r[VR_OUT] = comp_step(&c->comp, c->r[VR_IN]);
        c->i[VR_STATUS] = (int)c->comp.status;
#else
        plant_advance(&c->plant, c->r[VR_IN]);
#endif
    }
#endif
}

size_t inst_model_size(const Instance *c) {
    if (!c->built) return 0;
#if PASS_THROUGH || MODEL_KIND == KIND_SIGNAL
    return 0;
#elif MODEL_KIND == KIND_PID
    return 3;
#elif MODEL_KIND == KIND_HYST
    return 1 + fonbw_state_size(&c->hyst);
#elif MODEL_KIND == KIND_COMP
    return comp_state_size(&c->comp);
#else
    return (size_t)c->plant.n;
#endif
}

void inst_model_write(const Instance *c, double *d) {
#if PASS_THROUGH || MODEL_KIND == KIND_SIGNAL
    (void)c; (void)d;
#elif MODEL_KIND == KIND_PID
    d[0] = c->pid.i; d[1] = c->pid.e1; d[2] = c->pid.d1;
#elif MODEL_KIND == KIND_HYST
    d[0] = c->hyst_y0;
    fonbw_state_write(&c->hyst, d + 1);
#elif MODEL_KIND == KIND_COMP
    comp_state_write(&c->comp, d);
#else
    memcpy(d, c->plant.x, sizeof(double) * (size_t)c->plant.n);
#endif
}

int inst_model_read(Instance *c, const double *d, size_t nm) {
#if PASS_THROUGH || MODEL_KIND == KIND_SIGNAL
    (void)c; (void)d;
    return nm != 0 ? -1 : 0;
#elif MODEL_KIND == KIND_PID
    if (nm != 3) return -1;
    c->pid.i = d[0]; c->pid.e1 = d[1]; c->pid.d1 = d[2];
    return 0;
#elif MODEL_KIND == KIND_HYST
    if (nm < 1 || fonbw_state_read(&c->hyst, d + 1, nm - 1) != 0) return -1;
    c->hyst_y0 = d[0];
    return 0;
#elif MODEL_KIND == KIND_COMP
    return comp_state_read(&c->comp, d, nm);
#else
    if (nm != (size_t)c->plant.n) return -1;
    memcpy(c->plant.x, d, sizeof(double) * nm);
    return 0;
#endif
}
