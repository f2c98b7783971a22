/* Linear plant: exact zero-order-hold discretization and the stepping of
 * fonbw.plant.LinearStepper (y = C x + D u, x <- A x + B u). */
#include "fonbw_numerics.h"

#include <math.h>
#include <string.h>

#define NA (FONBW_MAX_STATES + 1)

static void matmul(int n, const double *X, const double *Y, double *Z) {
    int i, j, k;
    for (i = 0; i < n; i++)
        for (j = 0; j < n; j++) {
            double s = 0.0;
            for (k = 0; k < n; k++) s += X[i * n + k] * Y[k * n + j];
            Z[i * n + j] = s;
        }
}

/* solve P X = Q in place (Q becomes X), partial pivoting; -1 if singular */
static int solve(int n, double *P, double *Q) {
    int i, j, k;
    for (k = 0; k < n; k++) {
        int piv = k;
        for (i = k + 1; i < n; i++) if (fabs(P[i * n + k]) > fabs(P[piv * n + k])) piv = i;
        if (P[piv * n + k] == 0.0) return -1;
        if (piv != k)
            for (j = 0; j < n; j++) {
                double t = P[k * n + j]; P[k * n + j] = P[piv * n + j]; P[piv * n + j] = t;
                t = Q[k * n + j]; Q[k * n + j] = Q[piv * n + j]; Q[piv * n + j] = t;
            }
        for (i = k + 1; i < n; i++) {
            double f = P[i * n + k] / P[k * n + k];
            if (f == 0.0) continue;
            for (j = k; j < n; j++) P[i * n + j] -= f * P[k * n + j];
            for (j = 0; j < n; j++) Q[i * n + j] -= f * Q[k * n + j];
        }
    }
    for (k = n - 1; k >= 0; k--)
        for (j = 0; j < n; j++) {
            double s = Q[k * n + j];
            for (i = k + 1; i < n; i++) s -= P[k * n + i] * Q[i * n + j];
            Q[k * n + j] = s / P[k * n + k];
        }
    return 0;
}

/* exp(X) by the [13/13] Pade approximant with scaling and squaring (Higham 2005) */
static int expm(int n, const double *X, double *E) {
    static const double b[14] = {64764752532480000., 32382376266240000., 7771770303897600.,
        1187353796428800., 129060195264000., 10559470521600., 670442572800., 33522128640.,
        1323241920., 40840800., 960960., 16380., 182., 1.};
    double A[NA * NA], A2[NA * NA], A4[NA * NA], A6[NA * NA], U[NA * NA], V[NA * NA], T[NA * NA];
    double norm = 0.0, sc;
    int i, j, s = 0, nn = n * n;
    for (j = 0; j < n; j++) {
        double c = 0.0;
        for (i = 0; i < n; i++) c += fabs(X[i * n + j]);
        if (c > norm) norm = c;
    }
    if (!isfinite(norm)) return -1;
    if (norm > 5.371920351148152) s = (int)ceil(log2(norm / 5.371920351148152));
    sc = ldexp(1.0, -s);
    for (i = 0; i < nn; i++) A[i] = X[i] * sc;
    matmul(n, A, A, A2); matmul(n, A2, A2, A4); matmul(n, A4, A2, A6);
    for (i = 0; i < nn; i++) {
        T[i] = b[13] * A6[i] + b[11] * A4[i] + b[9] * A2[i];
        V[i] = b[12] * A6[i] + b[10] * A4[i] + b[8] * A2[i];
    }
    matmul(n, A6, T, U);
    matmul(n, A6, V, E);
    for (i = 0; i < nn; i++) {
        T[i] = U[i] + b[7] * A6[i] + b[5] * A4[i] + b[3] * A2[i];
        V[i] = E[i] + b[6] * A6[i] + b[4] * A4[i] + b[2] * A2[i];
    }
    for (i = 0; i < n; i++) { T[i * n + i] += b[1]; V[i * n + i] += b[0]; }
    matmul(n, A, T, U);
    for (i = 0; i < nn; i++) { T[i] = V[i] - U[i]; E[i] = V[i] + U[i]; }
    if (solve(n, T, E) != 0) return -1;
    for (; s > 0; s--) { matmul(n, E, E, T); memcpy(E, T, sizeof(double) * (size_t)nn); }
    return 0;
}

int plant_c2d(int n, const double *Ac, const double *Bc, double dt, double *Ad, double *Bd) {
    double M[NA * NA], E[NA * NA];
    int i, j, m = n + 1;
    if (n < 1 || n > FONBW_MAX_STATES) return -1;
    memset(M, 0, sizeof M);
    for (i = 0; i < n; i++) {
        for (j = 0; j < n; j++) M[i * m + j] = Ac[i * n + j] * dt;
        M[i * m + n] = Bc[i] * dt;
    }
    if (expm(m, M, E) != 0) return -1;
    for (i = 0; i < n; i++) {
        for (j = 0; j < n; j++) Ad[i * n + j] = E[i * m + j];
        Bd[i] = E[i * m + n];
    }
    for (i = 0; i < n * n; i++) if (!isfinite(Ad[i])) return -1;
    return 0;
}

double plant_output(const Plant *p, double u) {
    double acc = p->D * u;
    int i;
    for (i = 0; i < p->n; i++) acc += p->C[i] * p->x[i];
    return acc;
}

void plant_advance(Plant *p, double u) {
    double xn[FONBW_MAX_STATES];
    int i, j, n = p->n;
    for (i = 0; i < n; i++) {
        double s = p->B[i] * u;
        for (j = 0; j < n; j++) s += p->A[i * n + j] * p->x[j];
        xn[i] = s;
    }
    memcpy(p->x, xn, sizeof(double) * (size_t)n);
}
