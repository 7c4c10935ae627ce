/*
 * actuator.c -- hydraulic rotary actuator acting as a stiff position servo that
 * moves the footplate (system.h interface; see README.md for the equations).
 *
 * Units: rad, rad/s, rad/s^2, N m, kg m^2, N m/rad, Hz, s.
 *
 *   motor (servo loop):  theta_m'' = wn^2 (command - theta_m) - 2 zeta wn theta_m'
 *                        wn = 2 pi servo_bandwidth, zeta = servo_damping
 *   footplate:           J theta'' = K_s (theta_m - theta) + B_c (theta_m' - theta') - load_torque
 *                        B_c = 2 zeta_c sqrt(K_s J), zeta_c = coupling_damping
 *
 * State x = [theta_m, omega_m, theta, omega]; inputs u = [command, load_torque];
 * outputs y = [theta, omega, theta''] (acceleration has direct feedthrough of
 * load_torque); parameters p = [servo_bandwidth, servo_damping, footplate_inertia,
 * servo_stiffness, coupling_damping, initial_position].
 *
 * Discretisation: exact zero-order hold. With M = [[A, B], [0, 0]],
 * exp(M h) = [[Phi, Gamma], [0, I]] and x(k+1) = Phi x(k) + Gamma u(k), exact for
 * inputs held over the step whatever the stiffness (no stability limit). The
 * system.h contract gives a system no per-instance memory, so Phi and Gamma are
 * recomputed at every internal step (scaling and squaring, Taylor degree 12,
 * block-triangular products: about 2,200 multiply-adds, ~1 us); they depend only on
 * the parameters, which are fixed, so every step computes the same matrices.
 *
 * Error codes (returned by all three functions when a parameter is invalid):
 *   1 servo_bandwidth <= 0     2 servo_damping <= 0     3 footplate_inertia <= 0
 *   4 servo_stiffness <= 0     5 coupling_damping < 0   6 matrix exponential failed
 *
 * No libm dependency (own square root), no global mutable data.
 */
#include <string.h>

#include "system.h"

#if SYS_NX != 4 || SYS_NU != 2 || SYS_NY != 3 || SYS_NP != 6
#error "actuator.c expects SYS_NX=4, SYS_NU=2, SYS_NY=3, SYS_NP=6"
#endif

enum { P_BANDWIDTH, P_DAMPING, P_INERTIA, P_STIFFNESS, P_COUPLING, P_INITIAL };
enum { U_COMMAND, U_LOAD };
enum { X_THETA_M, X_OMEGA_M, X_THETA, X_OMEGA };

#define N 4                /* states */
#define M 2                /* inputs */
#define PI 3.14159265358979323846

typedef struct {
    double wn, zeta, J, K, Bc;
} Coefficients;

/* square root of a > 0 without libm: scale to [0.25, 4) by powers of 4, then Newton */
static double sqrt_pos(double a)
{
    double y, scale = 1.0;
    int i;
    if (!(a > 0.0)) return 0.0;
    while (a >= 4.0) {
        a *= 0.25;
        scale *= 2.0;
    }
    while (a < 0.25) {
        a *= 4.0;
        scale *= 0.5;
    }
    y = 0.5 * (a + 1.0);
    for (i = 0; i < 7; i++) y = 0.5 * (y + a / y);
    return y * scale;
}

static int coefficients(const double *p, Coefficients *c)
{
    /* written as !(v > 0) so that NaN parameters are rejected too */
    if (!(p[P_BANDWIDTH] > 0.0)) return 1;
    if (!(p[P_DAMPING] > 0.0)) return 2;
    if (!(p[P_INERTIA] > 0.0)) return 3;
    if (!(p[P_STIFFNESS] > 0.0)) return 4;
    if (!(p[P_COUPLING] >= 0.0)) return 5;
    c->wn = 2.0 * PI * p[P_BANDWIDTH];
    c->zeta = p[P_DAMPING];
    c->J = p[P_INERTIA];
    c->K = p[P_STIFFNESS];
    c->Bc = 2.0 * p[P_COUPLING] * sqrt_pos(c->K * c->J);
    return 0;
}

/* continuous-time A (N x N) and B (N x M), row-major */
static void continuous_model(const Coefficients *c, double A[N][N], double B[N][M])
{
    memset(A, 0, sizeof(double) * N * N);
    memset(B, 0, sizeof(double) * N * M);
    A[X_THETA_M][X_OMEGA_M] = 1.0;
    A[X_OMEGA_M][X_THETA_M] = -c->wn * c->wn;
    A[X_OMEGA_M][X_OMEGA_M] = -2.0 * c->zeta * c->wn;
    B[X_OMEGA_M][U_COMMAND] = c->wn * c->wn;
    A[X_THETA][X_OMEGA] = 1.0;
    A[X_OMEGA][X_THETA_M] = c->K / c->J;
    A[X_OMEGA][X_OMEGA_M] = c->Bc / c->J;
    A[X_OMEGA][X_THETA] = -c->K / c->J;
    A[X_OMEGA][X_OMEGA] = -c->Bc / c->J;
    B[X_OMEGA][U_LOAD] = -1.0 / c->J;
}

/*
 * Zero-order-hold discretisation: exp([[A, B], [0, 0]] h) = [[Phi, Gamma], [0, I]].
 * Matrices of the form [[E, F], [0, I]] (or [[X, Y], [0, 0]]) are stored by their top
 * block rows only; products keep that structure:
 *   [[X, Y], [0, 0]] [[E, F], [0, I]] = [[X E, X F + Y], [0, 0]]
 *   [[E, F], [0, I]]^2                 = [[E E, E F + F], [0, I]]
 */
static int discretise(const Coefficients *c, double h, double Phi[N][N], double Gam[N][M])
{
    double A[N][N], B[N][M], X[N][N], Y[N][M], E[N][N], F[N][M], T[N][N], G[N][M];
    double norm = 0.0, scale = 1.0;
    int i, j, l, k, s = 0;

    continuous_model(c, A, B);
    /* 1-norm of [[A, B], [0, 0]] h */
    for (j = 0; j < N + M; j++) {
        double col = 0.0;
        for (i = 0; i < N; i++) {
            double v = j < N ? A[i][j] : B[i][j - N];
            col += v < 0.0 ? -v * h : v * h;
        }
        if (col > norm) norm = col;
    }
    if (!(norm < 1e300)) return 6;
    while (norm > 0.25) { /* ||X|| <= 1/4: Taylor degree 12 error < 3e-18 */
        norm *= 0.5;
        scale *= 0.5;
        if (++s > 200) return 6;
    }
    for (i = 0; i < N; i++) {
        for (j = 0; j < N; j++) X[i][j] = A[i][j] * h * scale;
        for (j = 0; j < M; j++) Y[i][j] = B[i][j] * h * scale;
    }
    /* Horner: E <- I + X E / k, F <- (X F + Y) / k, for k = 12 .. 1, from E = I, F = 0 */
    memset(E, 0, sizeof E);
    memset(F, 0, sizeof F);
    for (i = 0; i < N; i++) E[i][i] = 1.0;
    for (k = 12; k >= 1; k--) {
        const double r = 1.0 / (double)k;
        for (i = 0; i < N; i++) {
            for (j = 0; j < N; j++) {
                double acc = 0.0;
                for (l = 0; l < N; l++) acc += X[i][l] * E[l][j];
                T[i][j] = (i == j ? 1.0 : 0.0) + acc * r;
            }
            for (j = 0; j < M; j++) {
                double acc = Y[i][j];
                for (l = 0; l < N; l++) acc += X[i][l] * F[l][j];
                G[i][j] = acc * r;
            }
        }
        memcpy(E, T, sizeof E);
        memcpy(F, G, sizeof F);
    }
    /* undo the scaling: square s times */
    for (k = 0; k < s; k++) {
        for (i = 0; i < N; i++) {
            for (j = 0; j < N; j++) {
                double acc = 0.0;
                for (l = 0; l < N; l++) acc += E[i][l] * E[l][j];
                T[i][j] = acc;
            }
            for (j = 0; j < M; j++) {
                double acc = F[i][j];
                for (l = 0; l < N; l++) acc += E[i][l] * F[l][j];
                G[i][j] = acc;
            }
        }
        memcpy(E, T, sizeof E);
        memcpy(F, G, sizeof F);
    }
    memcpy(Phi, E, sizeof E);
    memcpy(Gam, F, sizeof F);
    return 0;
}

int sys_initial_state(const double *p, double *x)
{
    Coefficients c;
    int rc = coefficients(p, &c);
    if (rc) return rc;
    /* at rest at the initial position, footplate undeflected */
    x[X_THETA_M] = p[P_INITIAL];
    x[X_OMEGA_M] = 0.0;
    x[X_THETA] = p[P_INITIAL];
    x[X_OMEGA] = 0.0;
    return 0;
}

int sys_output(const double *x, const double *u, const double *p, double *y)
{
    Coefficients c;
    int rc = coefficients(p, &c);
    if (rc) return rc;
    y[0] = x[X_THETA];
    y[1] = x[X_OMEGA];
    y[2] = (c.K * (x[X_THETA_M] - x[X_THETA]) + c.Bc * (x[X_OMEGA_M] - x[X_OMEGA]) - u[U_LOAD]) / c.J;
    return 0;
}

int sys_update(const double *x, const double *u, const double *p, double *x_next)
{
    Coefficients c;
    double Phi[N][N], Gam[N][M];
    int i, j, rc = coefficients(p, &c);
    if (rc) return rc;
    rc = discretise(&c, (double)SYS_STEP, Phi, Gam);
    if (rc) return rc;
    for (i = 0; i < N; i++) {
        double acc = 0.0;
        for (j = 0; j < N; j++) acc += Phi[i][j] * x[j];
        for (j = 0; j < M; j++) acc += Gam[i][j] * u[j];
        x_next[i] = acc;
    }
    return 0;
}
