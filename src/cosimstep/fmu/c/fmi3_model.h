/* What a model written for fmi3_frame.h declares its variables and events with. */
#ifndef COSIMSTEP_FMI3_MODEL_H
#define COSIMSTEP_FMI3_MODEL_H

#include "fmi3.h"

/* T_BINARY: offset is the index into State.bin (a model with N_BINARY > 0 declares
 * unsigned char bin[N_BINARY][BINARY_MAX] and size_t bin_size[N_BINARY] in its State). */
typedef enum { T_FLOAT64, T_INT32, T_BOOLEAN, T_BINARY } VarType;

#define BINARY_MAX 64 /* bytes in one Binary value */

/* K_STATE: a continuous state, settable before initialization ends; K_DISCRETE_INPUT: an
 * input that may change only in event mode (model exchange) or between steps. */
typedef enum {
    K_INDEPENDENT, K_PARAMETER, K_STATE, K_INPUT, K_DISCRETE_INPUT, K_OUTPUT, K_LOCAL
} VarKind;

typedef struct {
    VarType type;
    int offset; /* first element in State.v */
    int size;   /* elements (arrays: row-major) */
    VarKind kind;
} Var;

/* What model_event reports at an event. */
typedef struct {
    int values_changed; /* continuous states were re-initialized */
    int terminate;      /* the simulation should end here */
    int time_defined;   /* next_time is the next time event */
    double next_time;
} Event;

#endif /* COSIMSTEP_FMI3_MODEL_H */
