/* A ramp as an FMI 2.0 model-exchange FMU: cosimstep's test of a discrete real input.
 *
 * State x, der(x) = rate, where `rate` is an input of variability "discrete": as the standard
 * says, it can be set only before initialization ends or in event mode (a set in continuous-time
 * mode is an error). Output x.
 */
#include <string.h>

#include "fmi2me.h"

#define MODEL_GUID "{2b7e4c19-8d3a-4f60-9e1b-5a6c7d8e9f21}"
#define N_STATES 1
#define N_INDICATORS 0
#define CAN_GET_SET_STATE 1

enum { VR_X, VR_RATE, VR_DER_X, N_VR };

typedef struct {
    double time;
    double v[N_VR];
} State;

static const fmi2ValueReference STATE_VR[N_STATES] = {VR_X};

static void model_start(State *s) { memset(s->v, 0, sizeof s->v); }

static int model_settable(fmi2ValueReference vr, int before_initialization_ends,
                          int in_event_mode) {
    if (vr == VR_RATE) return before_initialization_ends || in_event_mode;
    return before_initialization_ends && vr == VR_X;
}

static const char *model_check(const State *s) {
    (void)s;
    return NULL;
}

static void model_derivatives(State *s, double dx[N_STATES]) {
    dx[0] = s->v[VR_RATE];
    s->v[VR_DER_X] = dx[0];
}

static void model_indicators(const State *s, double z[]) {
    (void)s;
    (void)z;
}

static void model_event(State *s, fmi2EventInfo *info) {
    (void)s;
    (void)info;
}

#include "fmi2_me_frame.h"
