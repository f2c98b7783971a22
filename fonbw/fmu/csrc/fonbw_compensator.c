/* The causal compensator: per-step inverse of the FONBW step map by trial
 * steps (fonbw/compensate/kernels.py: secant from the previous voltage,
 * Brent once a sign change brackets the root, the whole voltage range as the
 * fallback). */
#include "fonbw_numerics.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#define EPS 2.220446049250313e-16

static int same_sign(double a, double b) { return (a > 0.0) == (b > 0.0); }

static double trial(Compensator *c, double u, double hd) { return fonbw_step(&c->m, u, 0) - hd; }

typedef struct { double x, f; int status, n; double slope; } Root;

/* Brent's zeroin on a bracket; returns the last iterate, its contrapoint c */
static int brent(Compensator *cp, double hd, double a, double fa, double b, double fb,
                 double *xb, double *fxb, double *xc, double *fxc) {
    double c = a, fc = fa, d = b - a, e = d, tol = cp->tol;
    int n = 0, it;
    for (it = 0; it < cp->maxit; it++) {
        double tol1, xm;
        if (same_sign(fb, fc)) { c = a; fc = fa; d = b - a; e = d; }
        if (fabs(fc) < fabs(fb)) { a = b; fa = fb; b = c; fb = fc; c = a; fc = fa; }
        tol1 = 2.0 * EPS * fabs(b) + 1e-300;
        xm = 0.5 * (c - b);
        if (fabs(fb) <= tol || fabs(xm) <= tol1) break;
        if (fabs(e) >= tol1 && fabs(fa) > fabs(fb)) {
            double s = fb / fa, p, q, r, m1, m2;
            if (a == c) { p = 2.0 * xm * s; q = 1.0 - s; }
            else {
                q = fa / fc; r = fb / fc;
                p = s * (2.0 * xm * q * (q - r) - (b - a) * (r - 1.0));
                q = (q - 1.0) * (r - 1.0) * (s - 1.0);
            }
            if (p > 0.0) q = -q;
            p = fabs(p);
            m1 = 3.0 * xm * q - fabs(tol1 * q);
            m2 = fabs(e * q);
            if (2.0 * p < (m1 < m2 ? m1 : m2)) { e = d; d = p / q; }
            else { d = xm; e = d; }
        } else { d = xm; e = d; }
        a = b; fa = fb;
        if (fabs(d) > tol1) b = b + d;
        else b = b + (xm > 0.0 ? tol1 : -tol1);
        fb = trial(cp, b, hd);
        n++;
        if (!isfinite(fb)) break;
    }
    *xb = b; *fxb = fb; *xc = c; *fxc = fc;
    return n;
}

static Root bracketed(Compensator *cp, double hd, double a, double fa, double b, double fb,
                      int n, double bx, double bf, double slope) {
    double x, fx, c, fc;
    Root r;
    n += brent(cp, hd, a, fa, b, fb, &x, &fx, &c, &fc);
    if (fabs(fx) <= cp->tol) {
        r.x = x; r.f = fx; r.status = COMP_OK; r.n = n; r.slope = (x != c) ? (fx - fc) / (x - c) : slope;
        return r;
    }
    if (fabs(fx) < fabs(bf)) { bx = x; bf = fx; }
    r.x = bx; r.f = bf; r.status = COMP_NOT_CONVERGED; r.n = n; r.slope = slope;
    return r;
}

static Root result(double x, double f, int status, int n, double slope) {
    Root r;
    r.x = x; r.f = f; r.status = status; r.n = n; r.slope = slope;
    return r;
}

static double clamp(double x, double lo, double hi) {
    x = lo > x ? lo : x;
    return hi < x ? hi : x;
}

static Root solve(Compensator *cp, double hd, double x0, double slope) {
    double lo = cp->lo, hi = cp->hi, tol = cp->tol, f0, bx, bf, a, fa, flo, fhi, alo, ahi;
    int n = 1, it;
    x0 = clamp(x0, lo, hi);
    f0 = trial(cp, x0, hd);
    if (fabs(f0) <= tol) return result(x0, f0, COMP_OK, n, slope);
    bx = x0;
    bf = isfinite(f0) ? f0 : INFINITY;
    if (!(isfinite(slope) && slope != 0.0)) {
        double h = 1e-3 * (hi - lo), xb = x0 + h <= hi ? x0 + h : x0 - h, fb = trial(cp, xb, hd);
        n++;
        slope = (fb - f0) / (xb - x0);
    }
    a = x0; fa = f0;
    if (isfinite(f0) && isfinite(slope) && slope != 0.0) {
        double dx = -f0 / slope;
        for (it = 0; it < 12; it++) {
            double b = clamp(a + dx, lo, hi), fb;
            if (b == a) break;
            fb = trial(cp, b, hd);
            n++;
            if (!isfinite(fb)) break;
            if (fabs(fb) < fabs(bf)) { bx = b; bf = fb; }
            if (fabs(fb) <= tol) return result(b, fb, COMP_OK, n, (fb - fa) / (b - a));
            if (!same_sign(fa, fb)) return bracketed(cp, hd, a, fa, b, fb, n, bx, bf, slope);
            if (fabs(fb) >= fabs(fa)) break;
            dx = -fb * (b - a) / (fb - fa);
            slope = (fb - fa) / (b - a);
            a = b; fa = fb;
        }
    }
    flo = trial(cp, lo, hd);
    fhi = trial(cp, hi, hd);
    n += 2;
    if (isfinite(flo) && isfinite(fhi) && !same_sign(flo, fhi)) {
        if (isfinite(f0) && lo < x0 && x0 < hi) {
            if (same_sign(f0, flo)) return bracketed(cp, hd, x0, f0, hi, fhi, n, bx, bf, slope);
            return bracketed(cp, hd, lo, flo, x0, f0, n, bx, bf, slope);
        }
        return bracketed(cp, hd, lo, flo, hi, fhi, n, bx, bf, slope);
    }
    alo = isfinite(flo) ? fabs(flo) : INFINITY;
    ahi = isfinite(fhi) ? fabs(fhi) : INFINITY;
    if (alo <= ahi && alo <= fabs(bf)) return result(lo, flo, COMP_SAT_LOW, n, slope);
    if (ahi < alo && ahi <= fabs(bf)) return result(hi, fhi, COMP_SAT_HIGH, n, slope);
    return result(bx, bf, COMP_NOT_CONVERGED, n, slope);
}

void comp_reset(Compensator *c) {
    fonbw_reset(&c->m);
    c->y0 = 0.0;
    c->uprev = c->rest_n > 0 ? fonbw_rest_cycle(&c->m, c->rest_lo, c->rest_hi, c->rest_n, &c->y0) : clamp(0.0, c->lo, c->hi);
    c->slope = NAN;
    c->steps = c->n_sat = c->n_fail = c->status = c->y_model = 0.0;
}

int comp_init(Compensator *c, const FonbwParams *p, double dt, double lo, double hi,
              const double rest[3]) {
    if (fonbw_init(&c->m, p, dt) != 0) return -1;
    /* the library's default tolerance 1e-10, halved in its solve (its output is counted
     * from the zero of a start history, whose rounding must stay within 1e-10) */
    c->lo = lo; c->hi = hi; c->tol = 0.5 * 1e-10; c->maxit = 100;
    c->rest_lo = rest[0]; c->rest_hi = rest[1]; c->rest_n = fonbw_rest_samples(rest[2], dt);
    comp_reset(c);
    return 0;
}

void comp_free(Compensator *c) { fonbw_free(&c->m); }

double comp_step(Compensator *c, double hd) {
    Root r = solve(c, hd + c->y0, c->uprev, c->slope);
    c->slope = r.slope;
    c->y_model = fonbw_step(&c->m, r.x, 1) - c->y0;
    c->uprev = r.x;
    c->status = r.status;
    c->steps += 1.0;
    if (r.status == COMP_SAT_LOW || r.status == COMP_SAT_HIGH) c->n_sat += 1.0;
    else if (r.status == COMP_NOT_CONVERGED) c->n_fail += 1.0;
    return r.x;
}

#define COMP_NSCALAR 8

size_t comp_state_size(const Compensator *c) { return COMP_NSCALAR + fonbw_state_size(&c->m); }

void comp_state_write(const Compensator *c, double *s) {
    s[0] = c->uprev; s[1] = c->slope; s[2] = c->steps; s[3] = c->n_sat;
    s[4] = c->n_fail; s[5] = c->status; s[6] = c->y_model; s[7] = c->y0;
    fonbw_state_write(&c->m, s + COMP_NSCALAR);
}

int comp_state_read(Compensator *c, const double *s, size_t n) {
    if (n < COMP_NSCALAR || fonbw_state_read(&c->m, s + COMP_NSCALAR, n - COMP_NSCALAR) != 0) return -1;
    c->uprev = s[0]; c->slope = s[1]; c->steps = s[2]; c->n_sat = s[3];
    c->n_fail = s[4]; c->status = s[5]; c->y_model = s[6]; c->y0 = s[7];
    return 0;
}
