/* The ship plant's chiller (cosimstep.models.ship.chiller) as an FMI 2.0 co-simulation FMU.
 *
 * State and output: the supply temperature Ts of the chilled-water tank. Inputs: the three zone
 * temperatures and branch flows; each zone's heat exchanger passes eps q cp (T - Ts) with
 * eps = 1 - exp(-UA / (q cp)), and the chiller removes Kch (Ts - Tch), limited to [0, Qch_max].
 * The same equations as ship.chiller_rhs, integrated by RK4 with steps of at most max_dt.
 */
#define MODEL_GUID "{5d3f1c2a-8e4b-4f6a-9c1d-2b7e0a9f3c11}"
#define N_X 1
#define N_U 6
#define N_P 7

#include <math.h>

static const char *const VR_NAMES[N_X + N_U + N_P] = {
    "Ts", "T1", "T2", "T3", "q1", "q2", "q3",
    "cp", "UA", "Mw", "Kch", "Tch", "Qch_max", "max_dt"
};

static const double START[N_X + N_U + N_P] = {
    8.3, 22.0, 22.0, 22.0, 4.64621624, 4.61030063, 4.603837,
    4.186, 20.0, 2000.0, 200.0, 6.0, 800.0, 1.0
};

enum { P_CP, P_UA, P_MW, P_KCH, P_TCH, P_QMAX };

static double exchanger_heat(const double *par, double q, double t_zone, double t_supply) {
    const double capacity = (q > 0.0 ? q : 0.0) * par[P_CP];
    if (capacity <= 0.0) return 0.0;
    return (1.0 - exp(-par[P_UA] / capacity)) * capacity * (t_zone - t_supply);
}

static void model_rhs(const double *par, double t, const double *x, const double *u,
                      double *dx) {
    double picked = 0.0, removed = par[P_KCH] * (x[0] - par[P_TCH]);
    (void)t;
    for (int i = 0; i < 3; i++) picked += exchanger_heat(par, u[3 + i], u[i], x[0]);
    removed = fmin(fmax(removed, 0.0), par[P_QMAX]);
    dx[0] = (picked - removed) / (par[P_MW] * par[P_CP]);
}

static const char *model_check(const double *par) {
    if (!(par[P_CP] > 0.0 && par[P_MW] > 0.0 && par[P_UA] >= 0.0))
        return "cp and Mw must be positive and UA not negative";
    return 0;
}

#include "fmi2_cs_ode.h"
