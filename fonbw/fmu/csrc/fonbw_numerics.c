/* Numerics of the fonbw native FMUs (see fonbw_numerics.h). */
#include "fonbw_numerics.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define NEWTON_RTOL 1.1102230246251565e-16 /* 2^-53 */
#define POW_REFRESH 32.0
#define POW_SERIES_D 0.0078125             /* 2^-7 */
#define BRACKET_SNAP 3.0517578125e-05      /* 2^-15 */
#define EXACT_W0 1024
#define EPS 2.220446049250313e-16
#define PI 3.141592653589793

/* ---------------------------------------------------------------- sums */

/* sum a[j] b[j], j < n: eight lanes (lane t: j = t mod 8), a fixed tree, then the rest */
static double dot8(const double *a, const double *b, size_t n) {
    size_t nb8 = n >> 3, j, t;
    double s = 0.0;
    if (nb8 > 0) {
        double l[8] = {0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0};
        for (j = 0; j < nb8 << 3; j += 8)
            for (t = 0; t < 8; t++) l[t] += a[j + t] * b[j + t];
        s = ((l[0] + l[1]) + (l[2] + l[3])) + ((l[4] + l[5]) + (l[6] + l[7]));
    }
    for (j = nb8 << 3; j < n; j++) s += a[j] * b[j];
    return s;
}

/* z_i <- r_i (z_i + old); returns sum c_i z_i in the same lane order */
static double modes_push(const double *c, const double *r, double *z, size_t M, double old) {
    size_t nb8 = M >> 3, i, t;
    double l[8] = {0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0}, s;
    for (i = 0; i < nb8 << 3; i += 8)
        for (t = 0; t < 8; t++) {
            z[i + t] = r[i + t] * (z[i + t] + old);
            l[t] += c[i + t] * z[i + t];
        }
    s = ((l[0] + l[1]) + (l[2] + l[3])) + ((l[4] + l[5]) + (l[6] + l[7]));
    for (i = nb8 << 3; i < M; i++) {
        z[i] = r[i] * (z[i] + old);
        s += c[i] * z[i];
    }
    return s;
}

/* ------------------------------------------------------ GL operators */

static void gl_weights(double lam, double scale, double *w, int W) {
    double p = 1.0;
    int j;
    for (j = 1; j <= W; j++) {
        double f = 1.0 - (lam + 1.0) / (double)j;
        p = (j == 1) ? f : p * f;
        w[j - 1] = p * scale;
    }
}

/* the fast engine's tail modes: trapezoid rule in log s (weights.tail_modes) */
static void tail_modes(double lam, int K, int M, double scale, double *c, double *r) {
    double s_hi = 40.0 / ((double)K + 1.0 - lam), s_lo = 1e-9;
    double xlo = log(s_lo), xhi = log(s_hi), A = sin(PI * lam) / PI, step, hx, g;
    int i;
    step = M > 1 ? (xhi - xlo) / (double)(M - 1) : 0.0;  /* numpy.linspace */
    hx = M > 1 ? (1.0 * step + xlo) - (0.0 * step + xlo) : log(s_hi / s_lo);
    for (i = 0; i < M; i++) {
        double x = (M > 1 && i == M - 1) ? xhi : (double)i * step + xlo;
        double s = exp(x);
        double logf = lam * log(expm1(s)) - s * (double)K;
        c[i] = -A * hx * s * exp(logf);
        r[i] = exp(-s);
    }
    /* the nodes below s_lo, continued to -inf, summed into the lowest one */
    g = exp(-hx * (1.0 + lam));
    c[0] += -A * hx * pow(s_lo, 1.0 + lam) * g / (1.0 - g);
    for (i = 0; i < M; i++) c[i] = c[i] * scale;
}

static void op_free(FracOp *o) {
    free(o->w); free(o->c); free(o->r); free(o->buf); free(o->z);
    memset(o, 0, sizeof *o);
}

static int op_init(FracOp *o, double lam, double dt, int engine, int K, int M, int L) {
    memset(o, 0, sizeof *o);
    o->lam = lam;
    o->scale = pow(dt, -lam);
    o->a = o->scale;
    if (lam == 1.0) { o->W = 1; }
    else if (engine == ENGINE_EXACT) { o->W = EXACT_W0; o->growable = 1; }
    else if (engine == ENGINE_SHORT) { o->W = L; }
    else { o->W = K; o->M = M; }
    o->w = malloc(sizeof(double) * (size_t)o->W);
    o->buf = calloc((size_t)(o->growable ? o->W : 2 * o->W), sizeof(double));
    o->c = malloc(sizeof(double) * (size_t)(o->M + 1));
    o->r = malloc(sizeof(double) * (size_t)(o->M + 1));
    o->z = calloc((size_t)(o->M + 1), sizeof(double));
    if (!o->w || !o->buf || !o->c || !o->r || !o->z) { op_free(o); return -1; }
    if (lam == 1.0) o->w[0] = -o->scale;
    else gl_weights(lam, o->scale, o->w, o->W);
    if (o->M > 0) tail_modes(lam, K, o->M, o->scale, o->c, o->r);
    o->pos = o->growable ? o->W : 0;
    return 0;
}

static void op_reset(FracOp *o) {
    memset(o->buf, 0, sizeof(double) * (size_t)(o->growable ? o->W : 2 * o->W));
    memset(o->z, 0, sizeof(double) * (size_t)(o->M + 1));
    o->count = 0.0;
    o->hz = 0.0;
    o->pos = o->growable ? o->W : 0;
}

/* growable window: capacity W -> newW, samples kept newest-first at the end */
static int op_grow(FracOp *o, int newW) {
    int n = o->W - o->pos;
    double *w = malloc(sizeof(double) * (size_t)newW), *b = calloc((size_t)newW, sizeof(double));
    if (!w || !b) { free(w); free(b); return -1; }
    gl_weights(o->lam, o->scale, w, newW);
    memcpy(b + newW - n, o->buf + o->pos, sizeof(double) * (size_t)n);
    free(o->w); free(o->buf);
    o->w = w; o->buf = b; o->pos = newW - n; o->W = newW;
    return 0;
}

static double op_history(const FracOp *o) {
    size_t n = (o->count >= (double)o->W) ? (size_t)o->W : (size_t)o->count;
    return dot8(o->w, o->buf + o->pos, n) + o->hz;
}

static int op_push(FracOp *o, double x) {
    if (o->growable) {
        if (o->pos == 0 && op_grow(o, 2 * o->W) != 0) return -1;
        o->buf[--o->pos] = x;
    } else {
        int pos = (o->pos == 0 ? o->W : o->pos) - 1;
        if (o->M > 0) o->hz = modes_push(o->c, o->r, o->z, (size_t)o->M, o->buf[pos]);
        o->buf[pos] = x;
        o->buf[pos + o->W] = x;
        o->pos = pos;
    }
    o->count += 1.0;
    return 0;
}

static size_t op_state_size(const FracOp *o) {
    return 4 + (size_t)(o->growable ? o->W : 2 * o->W) + (size_t)o->M;
}

static double *op_state_write(const FracOp *o, double *s) {
    size_t nb = (size_t)(o->growable ? o->W : 2 * o->W);
    s[0] = o->W; s[1] = o->count; s[2] = o->hz; s[3] = o->pos;
    memcpy(s + 4, o->buf, sizeof(double) * nb);
    memcpy(s + 4 + nb, o->z, sizeof(double) * (size_t)o->M);
    return s + 4 + nb + o->M;
}

/* NULL on a state that does not fit this operator */
static const double *op_state_read(FracOp *o, const double *s, const double *end) {
    int W = (int)s[0];
    size_t nb;
    if (end - s < 4 || s[0] != (double)W || W < 1) return NULL;
    if (W != o->W) {
        if (!o->growable || W < EXACT_W0) return NULL;
        {   /* the window grew: rebuild it empty, then copy */
            double *w = malloc(sizeof(double) * (size_t)W), *b = calloc((size_t)W, sizeof(double));
            if (!w || !b) { free(w); free(b); return NULL; }
            gl_weights(o->lam, o->scale, w, W);
            free(o->w); free(o->buf);
            o->w = w; o->buf = b; o->W = W;
        }
    }
    nb = (size_t)(o->growable ? W : 2 * W);
    if ((size_t)(end - s) < 4 + nb + (size_t)o->M || s[3] < 0 || s[3] > W || s[1] < 0) return NULL;
    o->count = s[1]; o->hz = s[2]; o->pos = (int)s[3];
    memcpy(o->buf, s + 4, sizeof(double) * nb);
    memcpy(o->z, s + 4 + nb, sizeof(double) * (size_t)o->M);
    return s + 4 + nb + o->M;
}

/* ------------------------------------------------- Bouc-Wen solve */

static double powm1(double ax, double n) {
    if (n == 1.0) return 1.0;
    if (ax == 0.0) return 0.0;
    if (n == 2.0) return ax;
    if (n == 3.0) return ax * ax;
    return pow(ax, n - 1.0);
}

static double bw_residual(double x, double b, double c1, double c2, double n) {
    double ax = fabs(x), p = powm1(ax, n);
    return x - b + c1 * p * x + c2 * p * ax;
}

static double solve_bw_full(double b, double c1, double c2, double n, double x0, double p0) {
    double lo, hi, x, k2;
    int known, it;
    if (!(isfinite(b) && isfinite(c1) && isfinite(c2))) return NAN;
    if (b == 0.0) return 0.0;
    lo = b < 0.0 ? b : 0.0;
    hi = b > 0.0 ? b : 0.0;
    if (c1 < fabs(c2)) {
        double flo = bw_residual(lo, b, c1, c2, n), fhi = bw_residual(hi, b, c1, c2, n);
        for (it = 0; flo > 0.0 && it < 200; it++) { lo = 2.0 * lo - 1.0; flo = bw_residual(lo, b, c1, c2, n); }
        for (it = 0; fhi < 0.0 && it < 200; it++) { hi = 2.0 * hi + 1.0; fhi = bw_residual(hi, b, c1, c2, n); }
        if (flo > 0.0 || fhi < 0.0 || !(isfinite(flo) && isfinite(fhi))) return NAN;
    }
    if (isfinite(x0)) { x = lo > x0 ? lo : x0; x = hi < x ? hi : x; }
    else x = 0.5 * (lo + hi);
    known = p0 >= 0.0 && x == x0;
    k2 = n * (n - 1.0);
    for (it = 0; it < 200; it++) {
        double ax = fabs(x), p, g, f, d, xn;
        if (known) { p = p0; known = 0; } else p = powm1(ax, n);
        g = x >= 0.0 ? c1 + c2 : c1 - c2;
        f = x - b + c1 * p * x + c2 * p * ax;
        if (f == 0.0) return x;
        if (f < 0.0) lo = x; else hi = x;
        d = 1.0 + n * p * g;
        xn = d > 0.0 ? x - f / d : 0.5 * (lo + hi);
        if (lo <= xn && xn <= hi) {
            double s = xn - x;
            if (ax > 0.0 && (xn > 0.0) == (x > 0.0) &&
                k2 * fabs(g) * p * s * s <= 2.0 * NEWTON_RTOL * d * ax * fabs(xn))
                return xn;
        } else {
            xn = 0.5 * (lo + hi);
        }
        if (hi - lo <= 4.4e-16 * (fabs(lo) > fabs(hi) ? fabs(lo) : fabs(hi)) || fabs(xn - x) <= 1e-300)
            return xn;
        x = xn;
    }
    return x;
}

static double solve_bw_p(double b, double c1, double c2, double n, double x0, double p0) {
    double lo = b < 0.0 ? b : 0.0, hi = b > 0.0 ? b : 0.0;
    if (p0 >= 0.0 && lo <= x0 && x0 <= hi && x0 != 0.0 && c1 >= fabs(c2) && isfinite(b) && isfinite(c1)) {
        double ax = fabs(x0), g = x0 >= 0.0 ? c1 + c2 : c1 - c2, f, d;
        f = x0 - b + c1 * p0 * x0 + c2 * p0 * ax;
        if (f == 0.0) return x0;
        if (f < 0.0) lo = x0; else hi = x0;
        d = 1.0 + n * p0 * g;
        if (d > 0.0) {
            double xn = x0 - f / d, s = xn - x0;
            if (lo <= xn && xn <= hi && (xn > 0.0) == (x0 > 0.0) &&
                n * (n - 1.0) * fabs(g) * p0 * s * s <= 2.0 * NEWTON_RTOL * d * ax * fabs(xn))
                return xn;
        }
    }
    return solve_bw_full(b, c1, c2, n, x0, p0);
}

/* ------------------------------------------------------------ FONBW */

const char *fonbw_check(const FonbwParams *p, double dt, char *msg, size_t len) {
    int i;
    for (i = 0; i < p->N; i++)
        if (!isfinite(p->ku[i])) { snprintf(msg, len, "ku%d = %.17g is not finite", i + 1, p->ku[i]); return msg; }
#define CHECK(cond, ...) if (!(cond)) { snprintf(msg, len, __VA_ARGS__); return msg; }
    CHECK(isfinite(p->kh), "kh = %.17g is not finite", p->kh)
    CHECK(isfinite(p->rho) && p->rho > 0.0, "rho = %.17g must be a finite number > 0", p->rho)
    CHECK(isfinite(p->sigma), "sigma = %.17g is not finite", p->sigma)
    CHECK(isfinite(p->n) && p->n >= 1.0, "n = %.17g must be a finite number >= 1", p->n)
    CHECK(isfinite(p->lam1) && p->lam1 > 0.0 && p->lam1 <= 1.0, "lam1 = %.17g must lie in (0, 1]", p->lam1)
    CHECK(isfinite(p->lam2) && p->lam2 > 0.0 && p->lam2 <= 1.0, "lam2 = %.17g must lie in (0, 1]", p->lam2)
    CHECK(isfinite(dt) && dt > 0.0, "dt = %.17g s must be a finite number > 0", dt)
    CHECK(p->engine >= ENGINE_FAST && p->engine <= ENGINE_SHORT,
          "memory must be one of fast, exact, short (oustaloup is not available in the native FMUs)")
    CHECK(p->K >= 1 && p->K <= 100000, "K = %d must lie in [1, 100000]", p->K)
    CHECK(p->M >= 0 && p->M <= 1000, "M = %d must lie in [0, 1000]", p->M)
    CHECK(p->L >= 1 && p->L <= 10000000, "L = %d must lie in [1, 10000000]", p->L)
#undef CHECK
    return NULL;
}

void fonbw_reset(Fonbw *m) {
    op_reset(&m->op1);
    op_reset(&m->op2);
    m->u0 = m->started = m->h1 = m->hcur = m->h2 = m->x0 = m->p0 = m->cnt = 0.0;
}

int fonbw_init(Fonbw *m, const FonbwParams *p, double dt) {
    double a = p->n - 1.0;
    memset(m, 0, sizeof *m);
    m->p = *p;
    if (op_init(&m->op1, p->lam1, dt, p->engine, p->K, p->M, p->L) != 0) return -1;
    if (op_init(&m->op2, p->lam2, dt, p->engine, p->K, p->M, p->L) != 0) { op_free(&m->op1); return -1; }
    m->B[0] = a;
    m->B[1] = a * (a - 1.0) / 2.0;
    m->B[2] = m->B[1] * (a - 2.0) / 3.0;
    m->B[3] = m->B[2] * (a - 3.0) / 4.0;
    m->B[4] = m->B[3] * (a - 4.0) / 5.0;
    m->B[5] = m->B[4] * (a - 5.0) / 6.0;
    m->B[6] = m->B[5] * (a - 6.0) / 7.0;
    return 0;
}

void fonbw_free(Fonbw *m) {
    op_free(&m->op1);
    op_free(&m->op2);
}

/* Newton start for the step after this one and its power (fonbw_predict) */
static void fonbw_predict(const Fonbw *m, double pred[3]) {
    double xq = 3.0 * m->h1 - 2.0 * m->h2, n = m->p.n;
    if (m->cnt < POW_REFRESH && m->x0 != 0.0 && m->started != 0.0 && n != 1.0 && n != 2.0 && n != 3.0) {
        double d = xq / m->x0 - 1.0;
        if (fabs(d) <= POW_SERIES_D) {
            const double *B = m->B;
            double ser = 1.0 + d * (B[0] + d * (B[1] + d * (B[2] + d * (B[3] + d * (B[4] + d * (B[5] + d * B[6]))))));
            pred[0] = xq; pred[1] = m->p0 * ser; pred[2] = m->cnt + 1.0;
            return;
        }
    }
    pred[0] = xq; pred[1] = powm1(fabs(xq), n); pred[2] = 0.0;
}

static double fonbw_solve(const Fonbw *m, double D1, double h2, double a2) {
    double rho = m->p.rho, sigma = m->p.sigma, ia2 = 1.0 / a2;
    double b = (rho * D1 - h2) * ia2, x0 = m->x0, p0 = m->started != 0.0 ? m->p0 : -1.0;
    if (p0 >= 0.0 && x0 != 0.0 && (b > 0.0 ? x0 > b : x0 < b)) {
        double d = b / x0 - 1.0;
        if (fabs(d) <= BRACKET_SNAP) {
            p0 = p0 * (1.0 + d * (m->B[0] + d * (m->B[1] + d * m->B[2])));
            x0 = b;
        }
    }
    return solve_bw_p(b, rho * sigma * fabs(D1) * ia2, rho * (1.0 - sigma) * D1 * ia2, m->p.n, x0, p0);
}

double fonbw_step(Fonbw *m, double u, int commit) {
    double pred[3], xk, D1, hb, g = 0.0;
    int i;
    fonbw_predict(m, pred);
    xk = u - (m->started == 0.0 ? u : m->u0);
    D1 = m->op1.a * xk + op_history(&m->op1);
    hb = fonbw_solve(m, D1, op_history(&m->op2), m->op2.a);
    m->hcur = hb;
    if (commit) {
        if (m->started == 0.0) { m->u0 = u; m->started = 1.0; }
        if (op_push(&m->op1, xk) != 0 || op_push(&m->op2, hb) != 0) return NAN;
        m->h2 = m->h1; m->h1 = hb;
        m->x0 = pred[0]; m->p0 = pred[1]; m->cnt = pred[2];
    }
    for (i = m->p.N - 1; i >= 0; i--) g = (g + m->p.ku[i]) * u;
    return g + m->p.kh * hb;
}

#define FONBW_NSCALAR 8

size_t fonbw_state_size(const Fonbw *m) {
    return FONBW_NSCALAR + op_state_size(&m->op1) + op_state_size(&m->op2);
}

void fonbw_state_write(const Fonbw *m, double *s) {
    s[0] = m->u0; s[1] = m->started; s[2] = m->h1; s[3] = m->hcur;
    s[4] = m->h2; s[5] = m->x0; s[6] = m->p0; s[7] = m->cnt;
    op_state_write(&m->op2, op_state_write(&m->op1, s + FONBW_NSCALAR));
}

int fonbw_state_read(Fonbw *m, const double *s, size_t n) {
    const double *end = s + n, *q;
    if (n < FONBW_NSCALAR) return -1;
    q = op_state_read(&m->op1, s + FONBW_NSCALAR, end);
    if (!q || !(q = op_state_read(&m->op2, q, end)) || q != end) return -1;
    m->u0 = s[0]; m->started = s[1]; m->h1 = s[2]; m->hcur = s[3];
    m->h2 = s[4]; m->x0 = s[5]; m->p0 = s[6]; m->cnt = s[7];
    return 0;
}

/* The rest cycle of fonbw/compensate/rest.py: n samples of a raised cosine from
 * the rest voltage (the point of [lo, hi] nearest 0 V) to hi and back, run
 * through the model; *y_end gets the output at its end, the voltage is returned. */
double fonbw_rest_cycle(Fonbw *m, double lo, double hi, long n, double *y_end) {
    const double PI2 = 6.283185307179586;
    double u0 = lo > 0.0 ? lo : 0.0, u = 0.0;
    long i;
    if (u0 > hi) u0 = hi;
    for (i = 1; i <= n; i++) {
        u = u0 + (hi - u0) * 0.5 * (1.0 - cos(PI2 * (double)i / (double)n));
        *y_end = fonbw_step(m, u, 1);
    }
    return u;
}

/* samples of a rest cycle of T s at step dt (0: none): the library's
 * max(round(T / dt), 8), rounding half to even as Python's round does */
long fonbw_rest_samples(double T, double dt) {
    long n;
    if (!(T > 0.0)) return 0;
    n = (long)nearbyint(T / dt);
    return n < 8 ? 8 : n;
}
