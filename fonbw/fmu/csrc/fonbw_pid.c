/* Discrete PID with derivative filter, output limits and anti-windup, with a
 * feedforward input added before the limits: a transcription of
 * fonbw.pid.PIDStepper.step inside fonbw.loop.LoopController.step, with the
 * same operations in the same order (compile with -ffp-contract=off). */
#include "fonbw_numerics.h"

#include <math.h>
#include <stdio.h>

static int finite_nonneg(double x) { return isfinite(x) && x >= 0.0; }

const char *pid_check(const Pid *p, char *msg, size_t len) {
    if (!finite_nonneg(p->kp) || !finite_nonneg(p->ki) || !finite_nonneg(p->kd)) {
        snprintf(msg, len, "kp = %.17g, ki = %.17g, kd = %.17g must be finite and >= 0", p->kp, p->ki, p->kd);
        return msg;
    }
    if (p->kp == 0.0 && p->ki == 0.0 && p->kd == 0.0) {
        snprintf(msg, len, "at least one of kp, ki, kd must be positive");
        return msg;
    }
    if (!(isfinite(p->dt) && p->dt > 0.0)) {
        snprintf(msg, len, "dt = %.17g s must be a finite number > 0", p->dt);
        return msg;
    }
    if (!(p->lo < p->hi)) {
        snprintf(msg, len, "need u_min < u_max, got u_min = %.17g V, u_max = %.17g V", p->lo, p->hi);
        return msg;
    }
    if (!finite_nonneg(p->Tf)) {
        snprintf(msg, len, "Tf = %.17g s must be finite and >= 0", p->Tf);
        return msg;
    }
    if (!(isfinite(p->Tt) && p->Tt > 0.0 && p->Tt >= p->dt)) {
        snprintf(msg, len, "Tt = %.17g s must be finite and >= dt = %.17g s", p->Tt, p->dt);
        return msg;
    }
    return NULL;
}

static double clip(double v, double lo, double hi) {
    double x = lo > v ? lo : v;  /* Python's min(max(v, lo), hi) */
    return hi < x ? hi : x;
}

double pid_step(Pid *p, double r, double y, double u_ff) {
    double lo = p->lo - u_ff, hi = p->hi - u_ff;
    double e = r - y, dt = p->dt, d = 0.0, i_out, inc, v, u, new_i;
    if (p->kd > 0.0) d = (p->Tf * p->d1 + p->kd * (e - p->e1)) / (p->Tf + dt);
    if (p->integrator == PID_FORWARD) {
        i_out = p->i;  /* integral of errors up to k-1 */
        inc = p->ki * dt * e;
    } else if (p->integrator == PID_BACKWARD) {
        inc = p->ki * dt * e;
        i_out = p->i + inc;
    } else {
        inc = 0.5 * p->ki * dt * (e + p->e1);
        i_out = p->i + inc;
    }
    v = p->kp * e + i_out + d;
    u = clip(v, lo, hi);
    if (p->anti_windup == AW_CLAMPING && u != v && (inc > 0.0) == (v > u) && inc != 0.0) {
        /* the increment would push further into saturation: hold */
        if (p->integrator != PID_FORWARD) {
            i_out = p->i;
            v = p->kp * e + i_out + d;
            u = clip(v, lo, hi);
        }
        inc = 0.0;
    }
    new_i = p->integrator == PID_FORWARD ? p->i + inc : i_out;
    if (p->anti_windup == AW_BACK_CALCULATION) new_i += (dt / p->Tt) * (u - v);
    p->i = new_i;
    p->e1 = e;
    p->d1 = d;
    return u_ff + u;
}
