/* A bouncing ball as an FMI 2.0 model-exchange FMU: cosimstep's test of state and time events.
 *
 * States: height h above the floor and velocity v; der(h) = v, der(v) = -g. Event indicator
 * z = h - floor, where the floor height is an input. When the ball reaches the floor moving
 * down, v := -e v (h is kept). Once a bounce leaves with less than v_min the ball rests on the
 * floor. A time event at t_kick adds `kick` to v (none with the default t_kick = -1). Outputs:
 * h, v and the number of bounces so far.
 */
#include <math.h>

#include <string.h>

#include "fmi2me.h"

#define MODEL_GUID "{9e4d3b2a-1c7f-4a6e-8b5d-0f2e6c9a7b11}"
#define N_STATES 2
#define N_INDICATORS 1
#define CAN_GET_SET_STATE 1

enum {
    VR_H, VR_V, VR_BOUNCES,      /* outputs; h and v are the continuous states */
    VR_FLOOR,                    /* input: height of the floor */
    VR_G, VR_E, VR_V_MIN, VR_T_KICK, VR_KICK, /* parameters */
    VR_DER_H, VR_DER_V,          /* state derivatives */
    N_VR
};

typedef struct {
    double time;
    double v[N_VR];
    int resting; /* discrete states */
    int kicked;
} State;

static const fmi2ValueReference STATE_VR[N_STATES] = {VR_H, VR_V};

static void model_start(State *s) {
    static const double start[N_VR] = {1.0, 0.0, 0.0, 0.0, 9.81, 0.7, 1e-3, -1.0, 0.0, 0.0,
                                       0.0};
    memcpy(s->v, start, sizeof start);
    s->resting = 0;
    s->kicked = 0;
}

static int model_settable(fmi2ValueReference vr, int before_initialization_ends,
                          int in_event_mode) {
    (void)in_event_mode;
    if (vr == VR_FLOOR) return 1;
    return before_initialization_ends && vr != VR_BOUNCES && vr < VR_DER_H;
}

static const char *model_check(const State *s) {
    if (!(s->v[VR_G] > 0.0)) return "parameter g must be positive";
    if (!(s->v[VR_E] >= 0.0 && s->v[VR_E] <= 1.0)) return "parameter e must be in [0, 1]";
    return NULL;
}

static void model_derivatives(State *s, double dx[N_STATES]) {
    dx[0] = s->resting ? 0.0 : s->v[VR_V];
    dx[1] = s->resting ? 0.0 : -s->v[VR_G];
    s->v[VR_DER_H] = dx[0];
    s->v[VR_DER_V] = dx[1];
}

static void model_indicators(const State *s, double z[]) {
    z[0] = s->resting ? 1.0 : s->v[VR_H] - s->v[VR_FLOOR];
}

static int kick_pending(const State *s) {
    return !s->kicked && s->v[VR_T_KICK] >= 0.0;
}

static void model_event(State *s, fmi2EventInfo *info) {
    if (kick_pending(s) && s->time >= s->v[VR_T_KICK]) {
        s->kicked = 1;
        s->resting = 0;
        s->v[VR_V] += s->v[VR_KICK];
        info->valuesOfContinuousStatesChanged = fmi2True;
    }
    if (!s->resting && s->v[VR_H] - s->v[VR_FLOOR] <= 0.0 && s->v[VR_V] < 0.0) {
        s->v[VR_V] = -s->v[VR_E] * s->v[VR_V];
        s->v[VR_BOUNCES] += 1.0;
        if (s->v[VR_V] < s->v[VR_V_MIN]) {
            s->resting = 1;
            s->v[VR_V] = 0.0;
            s->v[VR_H] = s->v[VR_FLOOR];
        }
        info->valuesOfContinuousStatesChanged = fmi2True;
    }
    if (kick_pending(s)) {
        info->nextEventTimeDefined = fmi2True;
        info->nextEventTime = s->v[VR_T_KICK];
    }
}

#include "fmi2_me_frame.h"
