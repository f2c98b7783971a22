/* Numerics of the fonbw native FMUs: C99, libc and libm only.
 *
 * A line-by-line transcription of the library's compiled kernels
 * (fonbw/fractional, fonbw/hysteresis/kernels.py, fonbw/compensate/kernels.py,
 * fonbw/plant.py), with the same operations in the same order: the history
 * sums in eight lanes combined in a fixed tree, the safeguarded Newton solve
 * with its predictor, the secant/Brent/bracket root finder of the
 * compensator. Compile without floating-point contraction (-ffp-contract=off)
 * to keep the library's rounding. */
#ifndef FONBW_NUMERICS_H
#define FONBW_NUMERICS_H

#include <stddef.h>

enum { ENGINE_FAST = 0, ENGINE_EXACT = 1, ENGINE_SHORT = 2 };
enum { COMP_OK = 0, COMP_SAT_LOW = 1, COMP_SAT_HIGH = 2, COMP_NOT_CONVERGED = 3 };

#define FONBW_MAX_KU 16
#define FONBW_MAX_STATES 32

/* One Grunwald-Letnikov derivative D^lam at step dt: D x_k = a x_k + h_k. */
typedef struct {
    int W, M;           /* lags summed exactly (current window), tail modes */
    int growable;       /* exact engine: the window grows with the run */
    double lam, scale;  /* order, dt^-lam */
    double a;           /* coefficient of the current sample */
    double *w;          /* w[j]: scaled weight of lag j+1, j < W */
    double *c, *r;      /* tail modes (scaled c) */
    /* state */
    double count;       /* samples pushed */
    double hz;          /* sum c_i z_i */
    int pos;            /* ring: index of lag 1; growable: start of the newest-first block */
    double *buf;        /* ring: 2W mirrored; growable: capacity W, newest-first from pos */
    double *z;          /* M mode states */
} FracOp;

typedef struct {
    int N;
    double ku[FONBW_MAX_KU], kh, rho, sigma, n, lam1, lam2;
    int engine, K, M, L;
} FonbwParams;

typedef struct {
    FonbwParams p;
    FracOp op1, op2;
    double B[7];        /* binomial coefficients of (1+d)^(n-1) */
    /* state: as the library's S[0..7] */
    double u0, started, h1, hcur, h2, x0, p0, cnt;
} Fonbw;

typedef struct {
    Fonbw m;
    double lo, hi, tol;
    int maxit;
    double uprev, slope;
    double steps, n_sat, n_fail, status, y_model;
    /* rest cycle run before t = 0 (rest_T = 0: none) and the model's output
     * at its end, from which the outputs are counted (fonbw/compensate/rest.py) */
    double rest_lo, rest_hi, y0;
    long rest_n;
} Compensator;

/* PID of fonbw.pid.PIDStepper inside fonbw.loop.LoopController */
enum { PID_FORWARD = 0, PID_BACKWARD = 1, PID_TUSTIN = 2 };
enum { AW_BACK_CALCULATION = 0, AW_CLAMPING = 1, AW_NONE = 2 };

typedef struct {
    double kp, ki, kd, dt, lo, hi, Tf, Tt;
    int integrator, anti_windup;
    double i, e1, d1;   /* state: integrator, previous error, previous filtered derivative */
} Pid;

typedef struct {
    int n;
    double A[FONBW_MAX_STATES * FONBW_MAX_STATES], B[FONBW_MAX_STATES], C[FONBW_MAX_STATES], D;
    double x[FONBW_MAX_STATES];
} Plant;

/* Parameter check: NULL if fine, else a message naming the parameter. */
const char *fonbw_check(const FonbwParams *p, double dt, char *msg, size_t len);
/* Build (weights, tail modes) from p and dt; 0 on success, -1 out of memory. */
int fonbw_init(Fonbw *m, const FonbwParams *p, double dt);
void fonbw_free(Fonbw *m);
void fonbw_reset(Fonbw *m);
/* One step of eqs. (9)-(11); commit 0: trial evaluation, nothing stored.
 * Returns H [um]; -1e308*... never: NaN on a divergent parameter set.
 * A growable window is extended before the step (returns NaN if out of memory). */
double fonbw_step(Fonbw *m, double u, int commit);

/* State as doubles: size, write, read (read checks the size, 0 on success). */
size_t fonbw_state_size(const Fonbw *m);
void fonbw_state_write(const Fonbw *m, double *s);
int fonbw_state_read(Fonbw *m, const double *s, size_t n);

/* the rest cycle before t = 0 (fonbw/compensate/rest.py) */
double fonbw_rest_cycle(Fonbw *m, double lo, double hi, long n, double *y_end);
long fonbw_rest_samples(double T, double dt);

int comp_init(Compensator *c, const FonbwParams *p, double dt, double lo, double hi,
              const double rest[3]);
void comp_free(Compensator *c);
void comp_reset(Compensator *c);
double comp_step(Compensator *c, double hd);
size_t comp_state_size(const Compensator *c);
void comp_state_write(const Compensator *c, double *s);
int comp_state_read(Compensator *c, const double *s, size_t n);

/* Exact zero-order-hold discretization of x' = Ac x + Bc u (Pade 13 with
 * scaling and squaring of the augmented matrix); 0 on success. */
int plant_c2d(int n, const double *Ac, const double *Bc, double dt, double *Ad, double *Bd);
double plant_output(const Plant *p, double u);
void plant_advance(Plant *p, double u);

/* Parameter check of PIDStepper: NULL if fine, else a message naming the parameter. */
const char *pid_check(const Pid *p, char *msg, size_t len);
/* One controller sample: u = sat(u_ff + PID(r - y)), the limits shifted by u_ff. */
double pid_step(Pid *p, double r, double y, double u_ff);

#endif
