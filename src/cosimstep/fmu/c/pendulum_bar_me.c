/* One bar of the split double pendulum as an FMI 2.0 model-exchange FMU.
 *
 * Compile with -DBAR=1 (upper bar) or -DBAR=2 (lower bar). The continuous states are this bar's
 * angle theta and angular velocity omega; the inputs are the other bar's angle and angular
 * velocity; the importer integrates. There are no event indicators, and the FMU does not offer
 * FMU state get/set (canGetAndSetFMUstate="false"), so an importer that rolls back restores the
 * continuous states and time itself — cosimstep's MeSubModel does.
 */
#include <string.h>

#include "fmi2me.h"
#include "pendulum_physics.h"

#if BAR == 1
#define MODEL_GUID "{2f6a9c1e-7d3b-4e58-a0c4-91b8e2d7f301}"
#define THETA_START 0.4
#define OTHER_THETA_START (-0.3)
#else
#define MODEL_GUID "{2f6a9c1e-7d3b-4e58-a0c4-91b8e2d7f302}"
#define THETA_START (-0.3)
#define OTHER_THETA_START 0.4
#endif

#define N_STATES 2
#define N_INDICATORS 0
#define CAN_GET_SET_STATE 0

/* Value references, as in modelDescription.xml. */
enum {
    VR_THETA, VR_OMEGA,           /* continuous states, outputs */
    VR_U_THETA, VR_U_OMEGA,       /* inputs: the other bar's angle and angular velocity */
    VR_M1, VR_M2, VR_L1, VR_L2, VR_G, /* parameters */
    VR_DER_THETA, VR_DER_OMEGA,   /* state derivatives */
    N_VR
};

typedef struct {
    double time;
    double v[N_VR];
} State;

static const fmi2ValueReference STATE_VR[N_STATES] = {VR_THETA, VR_OMEGA};

static void model_start(State *s) {
    static const double start[N_VR] = {THETA_START, 0.0, OTHER_THETA_START, 0.0,
                                       1.0, 1.0, 1.0, 1.0, 9.81, 0.0, 0.0};
    memcpy(s->v, start, sizeof start);
}

static int model_settable(fmi2ValueReference vr, int before_initialization_ends,
                          int in_event_mode) {
    (void)in_event_mode;
    if (vr == VR_U_THETA || vr == VR_U_OMEGA) return 1;
    return before_initialization_ends && vr < VR_DER_THETA;
}

static const char *model_check(const State *s) {
    const double *v = s->v;
    if (!(v[VR_M1] > 0.0 && v[VR_M2] > 0.0 && v[VR_L1] > 0.0 && v[VR_L2] > 0.0))
        return "masses and lengths must be positive";
    return NULL;
}

static void model_derivatives(State *s, double dx[N_STATES]) {
    const PendulumParameters p = {s->v[VR_M1], s->v[VR_M2], s->v[VR_L1], s->v[VR_L2],
                                  s->v[VR_G]};
    pendulum_rhs(&p, &s->v[VR_THETA], &s->v[VR_U_THETA], dx);
    s->v[VR_DER_THETA] = dx[0];
    s->v[VR_DER_OMEGA] = dx[1];
}

static void model_indicators(const State *s, double z[]) {
    (void)s;
    (void)z;
}

static void model_event(State *s, fmi2EventInfo *info) {
    (void)s;
    (void)info; /* no discrete states: nothing changes at an event */
}

#include "fmi2_me_frame.h"
