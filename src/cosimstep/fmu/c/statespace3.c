/* A linear state-space model with array variables, as an FMI 3.0 FMU (model exchange and
 * co-simulation): cosimstep's test of array ports and array parameters.
 *
 *   der(x) = A x + B u,   y = C x + D u,   x, u, y of size 2, A, B, C, D 2 x 2 (row-major).
 *
 * Co-simulation integrates with RK4, at most max_dt per internal step, inputs held over a step.
 * An Int32 array input k[2] (may change only in event mode or between steps) is passed to the
 * Int32 array output k_out[2]: cosimstep's test of integer arrays.
 */
#include <string.h>

#include "fmi3_model.h"

#define MODEL_TOKEN "{7c1e4a52-3b9d-4e08-a6f1-2d5c8e9b0a33}"
#define HAS_MODEL_EXCHANGE 1
#define HAS_CO_SIMULATION 1
#define N_STATES 2
#define N_INDICATORS 0

/* value references */
enum { VR_TIME, VR_A, VR_B, VR_C, VR_D, VR_U, VR_Y, VR_X, VR_DER_X, VR_MAX_DT, VR_K, VR_K_OUT,
       N_VR };
/* offsets in State.v */
enum { O_A = 0, O_B = 4, O_C = 8, O_D = 12, O_U = 16, O_Y = 18, O_X = 20, O_DER_X = 22,
       O_MAX_DT = 24, O_K = 25, O_K_OUT = 27, N_V = 29 };
#define X_OFFSET O_X
#define MAX_DT_OFFSET O_MAX_DT

typedef struct {
    double time;
    double v[N_V];
} State;

static const Var VARS[N_VR] = {
    {T_FLOAT64, 0, 1, K_INDEPENDENT},
    {T_FLOAT64, O_A, 4, K_PARAMETER},
    {T_FLOAT64, O_B, 4, K_PARAMETER},
    {T_FLOAT64, O_C, 4, K_PARAMETER},
    {T_FLOAT64, O_D, 4, K_PARAMETER},
    {T_FLOAT64, O_U, 2, K_INPUT},
    {T_FLOAT64, O_Y, 2, K_OUTPUT},
    {T_FLOAT64, O_X, 2, K_STATE},
    {T_FLOAT64, O_DER_X, 2, K_LOCAL},
    {T_FLOAT64, O_MAX_DT, 1, K_PARAMETER},
    {T_INT32, O_K, 2, K_DISCRETE_INPUT},
    {T_INT32, O_K_OUT, 2, K_OUTPUT},
};

static void model_start(State *s) {
    static const double start[N_V] = {
        0, 1, -4, -0.4,   /* A: a damped oscillator */
        0, 0, 1, 0,       /* B: u[1] forces x[2] */
        1, 0, 0, 1,       /* C: y = x */
        0, 0, 0, 0,       /* D: no feedthrough */
        0, 0,             /* u */
        0, 0,             /* y */
        1, 0,             /* x */
        0, 0,             /* der(x) */
        1e-3,             /* max_dt */
        3, 4,             /* k */
        3, 4,             /* k_out */
    };
    memcpy(s->v, start, sizeof start);
}

static const char *model_check(const State *s) {
    return s->v[O_MAX_DT] > 0.0 ? NULL : "max_dt must be positive";
}

/* out = M a + N b for 2 x 2 matrices M, N (row-major). */
static void affine(const double *m, const double *a, const double *n, const double *b,
                   double *out) {
    for (int i = 0; i < 2; i++)
        out[i] = m[2 * i] * a[0] + m[2 * i + 1] * a[1] + n[2 * i] * b[0] + n[2 * i + 1] * b[1];
}

static void model_derivatives(State *s, double dx[N_STATES]) {
    double *v = s->v;
    affine(&v[O_A], &v[O_X], &v[O_B], &v[O_U], dx);
    v[O_DER_X] = dx[0];
    v[O_DER_X + 1] = dx[1];
    affine(&v[O_C], &v[O_X], &v[O_D], &v[O_U], &v[O_Y]);
    v[O_K_OUT] = v[O_K];
    v[O_K_OUT + 1] = v[O_K + 1];
}

static void model_indicators(const State *s, double z[]) {
    (void)s;
    (void)z;
}

static void model_event(State *s, Event *e) {
    (void)s;
    (void)e;
}

#include "fmi3_frame.h"
