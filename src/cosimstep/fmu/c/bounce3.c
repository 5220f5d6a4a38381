/* A bouncing ball as an FMI 3.0 FMU: cosimstep's test of FMI 3.0 model exchange with state
 * events and non-real ports (recipe bounce3: model exchange only), and of co-simulation event
 * mode (recipe bounce3_cs, built with -DBOUNCE_CS=1: co-simulation too, RK4 steps of at most
 * max_dt, hasEventMode).
 *
 *   der(h) = v, der(v) = -g; at h = 0 falling: v := -e v, bounces := bounces + 1.
 * Event indicators h (impact) and v (apex: the boolean output `falling`, v <= 0, changes there). The
 * integer input `kicks` may change only in event mode; each increment adds kick_speed to v.
 * When bounces reaches max_bounces (> 0), the FMU asks to terminate the simulation. Binary
 * input `tag` (event mode only) is passed to Binary output `tag_out` (direct feedthrough).
 */
#include <string.h>

#include "fmi3_model.h"

#ifndef BOUNCE_CS
#define BOUNCE_CS 0
#endif
#if BOUNCE_CS
#define MODEL_TOKEN "{c4d2a9e7-6f13-4b58-8e0a-91b3f7d2c6e6}"
#else
#define MODEL_TOKEN "{c4d2a9e7-6f13-4b58-8e0a-91b3f7d2c6e5}"
#endif
#define HAS_MODEL_EXCHANGE 1
#define HAS_CO_SIMULATION BOUNCE_CS
#define N_STATES 2
#define N_INDICATORS 2
#define N_BINARY 2 /* tag, tag_out */

enum { VR_TIME, VR_H, VR_DER_H, VR_V, VR_DER_V, VR_G, VR_E, VR_BOUNCES, VR_FALLING, VR_KICKS,
       VR_KICK_SPEED, VR_MAX_BOUNCES, VR_MAX_DT, VR_TAG, VR_TAG_OUT, N_VR };
/* the states first (h, v), then the rest; O_KICKS_SEEN is internal (no value reference) */
enum { O_H, O_V, O_DER_H, O_DER_V, O_G, O_E, O_BOUNCES, O_FALLING, O_KICKS, O_KICK_SPEED,
       O_MAX_BOUNCES, O_MAX_DT, O_KICKS_SEEN, N_V };
#define X_OFFSET O_H
#define MAX_DT_OFFSET O_MAX_DT

typedef struct {
    double time;
    double v[N_V];
    unsigned char bin[N_BINARY][BINARY_MAX];
    size_t bin_size[N_BINARY];
} State;

static const Var VARS[N_VR] = {
    {T_FLOAT64, 0, 1, K_INDEPENDENT},
    {T_FLOAT64, O_H, 1, K_STATE},
    {T_FLOAT64, O_DER_H, 1, K_LOCAL},
    {T_FLOAT64, O_V, 1, K_STATE},
    {T_FLOAT64, O_DER_V, 1, K_LOCAL},
    {T_FLOAT64, O_G, 1, K_PARAMETER},
    {T_FLOAT64, O_E, 1, K_PARAMETER},
    {T_INT32, O_BOUNCES, 1, K_OUTPUT},
    {T_BOOLEAN, O_FALLING, 1, K_OUTPUT},
    {T_INT32, O_KICKS, 1, K_DISCRETE_INPUT},
    {T_FLOAT64, O_KICK_SPEED, 1, K_PARAMETER},
    {T_INT32, O_MAX_BOUNCES, 1, K_PARAMETER},
    {T_FLOAT64, O_MAX_DT, 1, K_PARAMETER},
    {T_BINARY, 0, 1, K_DISCRETE_INPUT},
    {T_BINARY, 1, 1, K_OUTPUT},
};

static void model_start(State *s) {
    memset(s, 0, sizeof *s);
    s->v[O_H] = 1.0;
    s->v[O_G] = 9.81;
    s->v[O_E] = 0.7;
    s->v[O_KICK_SPEED] = 2.0;
    s->v[O_FALLING] = 1.0;
    s->v[O_MAX_DT] = 1e-3;
    memcpy(s->bin[0], "\xc0\xff\xee", 3); /* tag: the model description's start c0ffee */
    s->bin_size[0] = 3;
}

static const char *model_check(const State *s) {
    if (!(s->v[O_G] > 0.0)) return "g must be positive";
    if (!(s->v[O_E] >= 0.0 && s->v[O_E] <= 1.0)) return "e must be in [0, 1]";
    if (!(s->v[O_MAX_DT] > 0.0)) return "max_dt must be positive";
    return NULL;
}

static void model_derivatives(State *s, double dx[N_STATES]) {
    dx[0] = s->v[O_V];
    dx[1] = -s->v[O_G];
    s->v[O_DER_H] = dx[0];
    s->v[O_DER_V] = dx[1];
    memcpy(s->bin[1], s->bin[0], s->bin_size[0]); /* tag_out = tag */
    s->bin_size[1] = s->bin_size[0];
}

static void model_indicators(const State *s, double z[]) {
    z[0] = s->v[O_H];
    z[1] = s->v[O_V];
}

static void model_event(State *s, Event *e) {
    double *v = s->v;
    if (v[O_H] <= 0.0 && v[O_V] < 0.0) { /* impact */
        v[O_H] = 0.0;
        v[O_V] = -v[O_E] * v[O_V];
        v[O_BOUNCES] += 1.0;
        e->values_changed = 1;
    }
    if (v[O_KICKS] != v[O_KICKS_SEEN]) { /* a new value of the discrete input */
        v[O_V] += (v[O_KICKS] - v[O_KICKS_SEEN]) * v[O_KICK_SPEED];
        v[O_KICKS_SEEN] = v[O_KICKS];
        e->values_changed = 1;
    }
    v[O_FALLING] = v[O_V] <= 0.0 ? 1.0 : 0.0;
    e->terminate = v[O_MAX_BOUNCES] > 0.0 && v[O_BOUNCES] >= v[O_MAX_BOUNCES];
}

#include "fmi3_frame.h"
