/* One bar of the split double pendulum as an FMI 2.0 co-simulation FMU.
 *
 * Compile with -DBAR=1 (upper bar) or -DBAR=2 (lower bar). The bar integrates its own angle theta
 * and angular velocity omega and receives the other bar's angle and angular velocity as inputs.
 * The numbers reproduce cosimstep.models.pendulum.bar(2, BAR, ...) driven by OdeSubModel with
 * RK4(max_dt): the generic frame (fmi2_cs_ode.h) takes the same Runge-Kutta stages, the same
 * number of local steps n = max(1, ceil(h / max_dt - 1e-9)), the same input polynomial
 * u + sum_k d_k dt^k / k! (k <= 3, set with fmi2SetRealInputDerivatives) and the same
 * re-expansion of that polynomial at the end of a step. Expressions keep Python's evaluation
 * order so results agree bit for bit; build without floating-point contraction
 * (-ffp-contract=off) for that.
 *
 * Setting an input with fmi2SetReal clears its derivatives, so a master that only sets values
 * gets inputs held constant over the step.
 */
#include "pendulum_physics.h"

#if BAR == 1
#define MODEL_GUID "{8c4e2d57-1b6f-4a0e-9d2c-3f5a7b9e1c01}"
#define THETA_START 0.4
#define OTHER_THETA_START (-0.3)
#else
#define MODEL_GUID "{8c4e2d57-1b6f-4a0e-9d2c-3f5a7b9e1c02}"
#define THETA_START (-0.3)
#define OTHER_THETA_START 0.4
#endif

#define N_X 2 /* outputs: this bar's theta, omega */
#define N_U 2 /* inputs: the other bar's angle and angular velocity */
#define N_P 6 /* m1, m2, l1, l2, g, max_dt */

static const char *const VR_NAMES[N_X + N_U + N_P] = {
    "theta", "omega",
#if BAR == 1
    "theta2", "omega2",
#else
    "theta1", "omega1",
#endif
    "m1", "m2", "l1", "l2", "g", "max_dt"
};

static const double START[N_X + N_U + N_P] = {
    THETA_START, 0.0, OTHER_THETA_START, 0.0, 1.0, 1.0, 1.0, 1.0, 9.81, 1e-3
};

/* This bar's dx/dt from the chain parameters (the physics is shared with the FMI 3.0 and
 * model-exchange bars). */
static void model_rhs(const double *par, double t, const double *x, const double *u,
                      double *dx) {
    const PendulumParameters p = {par[0], par[1], par[2], par[3], par[4]};
    (void)t;
    pendulum_rhs(&p, x, u, dx);
}

static const char *model_check(const double *par) {
    if (!(par[0] > 0.0 && par[1] > 0.0 && par[2] > 0.0 && par[3] > 0.0))
        return "masses and lengths must be positive";
    return 0;
}

#include "fmi2_cs_ode.h"
