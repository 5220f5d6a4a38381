/* Two small FMI 2.0 co-simulation FMUs with non-real variables, cosimstep's tests of discrete
 * ports (Integer, Boolean, String), built from this one file:
 *
 * -DKIND=1, "stair": no inputs and no real outputs. Integer output `counter` starts at 1 and
 *   steps up by one at every multiple of the Real parameter `period` (a time event inside the
 *   FMU: the value at the end of a step that ends on the event is already the new one); Boolean
 *   output `odd` is true while the counter is odd, String output `word` is "odd" or "even" with
 *   it; String parameter `label` is only kept (it can be set and read back, fmi2GetString). With Integer parameter `stop_at` > 0, the step in
 *   which the counter reaches it returns fmi2Discard and fmi2GetBooleanStatus(fmi2Terminated)
 *   says true: the FMU ends the simulation (FMI 2.0 terminateSimulation).
 * -DKIND=2, "echo": Integer input `n` and Boolean input `b`, passed straight to Integer output
 *   `n_out` and Boolean output `b_out` (direct feedthrough), String input `s` passed to String
 *   output `s_out` the same way, and Real output `x`, the integral of the integer input (exact
 *   for an input held over each step: x += n h).
 *
 * -DKIND=3, "loop_linear" and -DKIND=4, "loop_sphere": the two halves of a nonlinear algebraic
 *   loop (issue 18). loop_linear computes Real outputs a, b from a + b + c = 0 and
 *   2a - 3b + 2c = 9 given its Real input c; loop_sphere computes c = sqrt(5 - a^2 - b^2) from
 *   a^2 + b^2 + c^2 = 5 given its inputs a, b (NaN where there is no real root). Both have direct
 *   feedthrough; connected both ways they form the loop, whose roots are a = 1.8 - c, b = -1.8,
 *   2c^2 - 3.6c + 1.48 = 0: c = (3.6 + sqrt(1.12)) / 4 = 1.1645751... or (3.6 - sqrt(1.12)) / 4.
 *
 * FMU state get/set/serialize are offered (the state is a flat struct).
 */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2.h"

#if !defined(KIND) || KIND < 1 || KIND > 4
#error "compile with -DKIND=1 (stair), 2 (echo), 3 (loop_linear) or 4 (loop_sphere)"
#endif

#if KIND == 1
#define MODEL_GUID "{5d0c7a21-6e3b-4c8f-a1d2-7b9e3f0c2a11}"
#elif KIND == 2
#define MODEL_GUID "{5d0c7a21-6e3b-4c8f-a1d2-7b9e3f0c2a12}"
#elif KIND == 3
#define MODEL_GUID "{5d0c7a21-6e3b-4c8f-a1d2-7b9e3f0c2a13}"
#else
#define MODEL_GUID "{5d0c7a21-6e3b-4c8f-a1d2-7b9e3f0c2a14}"
#endif

#define LABEL_SIZE 64
#define STATE_MAGIC 0x43534432u /* "CSD2" */

/* Value references, as in the model descriptions: reals, integers, booleans, strings each
 * counted from 0 (FMI 2.0 value references are per type). */
enum { R_PERIOD = 0, R_X = 1, R_A = 2, R_B = 3, R_C = 4, N_REAL };
enum { I_COUNTER = 0, I_N = 1, I_N_OUT = 2, I_STOP = 3, N_INT };
enum { B_ODD = 0, B_B = 1, B_B_OUT = 2, N_BOOL };
enum { S_LABEL = 0, S_WORD = 1, S_S = 2, S_S_OUT = 3, N_STRING };

typedef struct {
    double time;
    double r[N_REAL];
    int i[N_INT];
    int b[N_BOOL];
    char str[N_STRING][LABEL_SIZE];
    int terminated; /* the stair reached `stop_at`: it asks to end the simulation */
} State;

typedef struct {
    State s;
    fmi2CallbackFunctions cb;
    char *name;
    fmi2Boolean logging;
} Instance;

static void fail_log(const Instance *inst, const char *fmt, ...) {
    char text[256];
    va_list args;
    if (!inst->cb.logger) return;
    va_start(args, fmt);
    vsnprintf(text, sizeof text, fmt, args);
    va_end(args);
    inst->cb.logger(inst->cb.componentEnvironment, inst->name, fmi2Error, "logStatusError",
                    "%s", text);
}

#define FAIL(inst, ...) (fail_log((inst), __VA_ARGS__), fmi2Error)

static Instance *as_instance(fmi2Component c) { return (Instance *)c; }

/* The stair's outputs at time t: counter 1 + the number of multiples of period in (0, t]. */
static void stair(State *s, double t) {
#if KIND == 1
    double steps = floor(t / s->r[R_PERIOD] + 1e-12);
    s->i[I_COUNTER] = 1 + (int)steps;
    s->b[B_ODD] = s->i[I_COUNTER] % 2 != 0;
    strcpy(s->str[S_WORD], s->b[B_ODD] ? "odd" : "even");
#else
    (void)s;
    (void)t;
#endif
}

static void feedthrough(State *s) {
#if KIND == 2
    s->i[I_N_OUT] = s->i[I_N];
    s->b[B_B_OUT] = s->b[B_B];
    strcpy(s->str[S_S_OUT], s->str[S_S]);
#elif KIND == 3
    /* a + b = -c and 2a - 3b = 9 - 2c, by Cramer's rule (determinant -5) */
    s->r[R_A] = (-3.0 * -s->r[R_C] - (9.0 - 2.0 * s->r[R_C])) / -5.0;
    s->r[R_B] = ((9.0 - 2.0 * s->r[R_C]) - 2.0 * -s->r[R_C]) / -5.0;
#elif KIND == 4
    s->r[R_C] = sqrt(5.0 - s->r[R_A] * s->r[R_A] - s->r[R_B] * s->r[R_B]);
#else
    (void)s;
#endif
}

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    (void)nCategories;
    (void)categories;
    as_instance(c)->logging = loggingOn;
    return fmi2OK;
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation,
                              const fmi2CallbackFunctions *functions, fmi2Boolean visible,
                              fmi2Boolean loggingOn) {
    (void)fmuResourceLocation;
    (void)visible;
    if (fmuType != fmi2CoSimulation || !fmuGUID || strcmp(fmuGUID, MODEL_GUID) != 0) return NULL;
    Instance *inst = calloc(1, sizeof *inst);
    if (!inst) return NULL;
    inst->cb = *functions;
    inst->logging = loggingOn;
    inst->name = malloc(strlen(instanceName ? instanceName : "") + 1);
    if (inst->name) strcpy(inst->name, instanceName ? instanceName : "");
    inst->s.r[R_PERIOD] = 1.0;
    inst->s.r[R_C] = KIND == 3 ? 1.0 : 0.0; /* loop_linear's input c starts at 1 */
    strcpy(inst->s.str[S_LABEL], "stair");
    stair(&inst->s, 0.0);
    return inst;
}

void fmi2FreeInstance(fmi2Component c) {
    Instance *inst = as_instance(c);
    if (!inst) return;
    free(inst->name);
    free(inst);
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined,
                               fmi2Real stopTime) {
    (void)toleranceDefined;
    (void)tolerance;
    (void)stopTimeDefined;
    (void)stopTime;
    as_instance(c)->s.time = startTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) { (void)c; return fmi2OK; }

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    Instance *inst = as_instance(c);
    if (KIND == 1 && !(inst->s.r[R_PERIOD] > 0))
        return FAIL(inst, "parameter period must be positive, got %g", inst->s.r[R_PERIOD]);
    stair(&inst->s, inst->s.time);
    feedthrough(&inst->s);
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component c) { (void)c; return fmi2OK; }

fmi2Status fmi2Reset(fmi2Component c) { (void)c; return fmi2OK; }

#define CHECK_VR(inst, vr, n, what)                                                      \
    if ((vr) >= (n)) return FAIL((inst), what ": no variable with value reference %u", \
                                 (unsigned)(vr))

/* fmi2Get<Type> / fmi2Set<Type> for the numeric types: one value array per type in the state
 * (a set of an input also updates the feedthrough outputs). */
#define GET_SET(Type, ctype, array, count, convert_in, convert_out)                         \
    fmi2Status fmi2Get##Type(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,    \
                             ctype value[]) {                                              \
        Instance *inst = as_instance(c);                                                   \
        for (size_t k = 0; k < nvr; k++) {                                                 \
            CHECK_VR(inst, vr[k], count, "fmi2Get" #Type);                                 \
            value[k] = convert_out(inst->s.array[vr[k]]);                                  \
        }                                                                                  \
        return fmi2OK;                                                                     \
    }                                                                                      \
    fmi2Status fmi2Set##Type(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,    \
                             const ctype value[]) {                                        \
        Instance *inst = as_instance(c);                                                   \
        for (size_t k = 0; k < nvr; k++) {                                                 \
            CHECK_VR(inst, vr[k], count, "fmi2Set" #Type);                                 \
            inst->s.array[vr[k]] = convert_in(value[k]);                                   \
        }                                                                                  \
        feedthrough(&inst->s);                                                             \
        return fmi2OK;                                                                     \
    }

#define AS_IS(x) (x)
#define TO_BOOL(x) ((x) != fmi2False)
#define FROM_BOOL(x) ((x) ? fmi2True : fmi2False)

GET_SET(Real, fmi2Real, r, N_REAL, AS_IS, AS_IS)
GET_SET(Integer, fmi2Integer, i, N_INT, AS_IS, AS_IS)
GET_SET(Boolean, fmi2Boolean, b, N_BOOL, TO_BOOL, FROM_BOOL)

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         fmi2String value[]) {
    Instance *inst = as_instance(c);
    for (size_t k = 0; k < nvr; k++) {
        CHECK_VR(inst, vr[k], N_STRING, "fmi2GetString");
        value[k] = inst->s.str[vr[k]];
    }
    return fmi2OK;
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         const fmi2String value[]) {
    Instance *inst = as_instance(c);
    for (size_t k = 0; k < nvr; k++) {
        CHECK_VR(inst, vr[k], N_STRING, "fmi2SetString");
        if (!value[k] || strlen(value[k]) >= LABEL_SIZE)
            return FAIL(inst, "fmi2SetString: a string must have fewer than %d characters",
                        LABEL_SIZE);
        strcpy(inst->s.str[vr[k]], value[k]);
    }
    feedthrough(&inst->s);
    return fmi2OK;
}

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    Instance *inst = as_instance(c);
    if (!*FMUstate) *FMUstate = malloc(sizeof(State));
    if (!*FMUstate) return FAIL(inst, "fmi2GetFMUstate: out of memory");
    memcpy(*FMUstate, &inst->s, sizeof(State));
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    memcpy(&as_instance(c)->s, FMUstate, sizeof(State));
    return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    (void)c;
    free(*FMUstate);
    *FMUstate = NULL;
    return fmi2OK;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size) {
    (void)c;
    (void)FMUstate;
    *size = sizeof(unsigned) + sizeof(State);
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate,
                                 fmi2Byte serializedState[], size_t size) {
    unsigned magic = STATE_MAGIC;
    if (size < sizeof magic + sizeof(State))
        return FAIL(as_instance(c), "fmi2SerializeFMUstate: buffer too small");
    memcpy(serializedState, &magic, sizeof magic);
    memcpy(serializedState + sizeof magic, FMUstate, sizeof(State));
    return fmi2OK;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[],
                                   size_t size, fmi2FMUstate *FMUstate) {
    unsigned magic;
    if (size != sizeof magic + sizeof(State))
        return FAIL(as_instance(c), "fmi2DeSerializeFMUstate: not a state of this FMU");
    memcpy(&magic, serializedState, sizeof magic);
    if (magic != STATE_MAGIC)
        return FAIL(as_instance(c), "fmi2DeSerializeFMUstate: not a state of this FMU");
    if (!*FMUstate) *FMUstate = malloc(sizeof(State));
    if (!*FMUstate) return FAIL(as_instance(c), "fmi2DeSerializeFMUstate: out of memory");
    memcpy(*FMUstate, serializedState + sizeof magic, sizeof(State));
    return fmi2OK;
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[],
                                        size_t nUnknown, const fmi2ValueReference vKnown_ref[],
                                        size_t nKnown, const fmi2Real dvKnown[],
                                        fmi2Real dvUnknown[]) {
    (void)vUnknown_ref, (void)nUnknown, (void)vKnown_ref, (void)nKnown, (void)dvKnown;
    (void)dvUnknown;
    return FAIL(as_instance(c), "fmi2GetDirectionalDerivative is not provided");
}

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    (void)vr, (void)nvr, (void)order, (void)value;
    return FAIL(as_instance(c), "fmi2SetRealInputDerivatives: no real inputs");
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[],
                                        size_t nvr, const fmi2Integer order[],
                                        fmi2Real value[]) {
    (void)vr, (void)nvr, (void)order, (void)value;
    return FAIL(as_instance(c), "fmi2GetRealOutputDerivatives is not provided");
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint,
                      fmi2Real communicationStepSize, fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    (void)noSetFMUStatePriorToCurrentPoint;
    Instance *inst = as_instance(c);
    if (!(communicationStepSize > 0))
        return FAIL(inst, "fmi2DoStep: step %g is not positive", communicationStepSize);
    double t = currentCommunicationPoint + communicationStepSize;
#if KIND == 2
    inst->s.r[R_X] += inst->s.i[I_N] * communicationStepSize;
#endif
    inst->s.time = t;
    stair(&inst->s, t);
#if KIND == 1
    if (inst->s.i[I_STOP] > 0 && inst->s.i[I_COUNTER] >= inst->s.i[I_STOP]) {
        inst->s.terminated = 1;
        return fmi2Discard;
    }
#endif
    return fmi2OK;
}

fmi2Status fmi2CancelStep(fmi2Component c) { (void)c; return fmi2Error; }

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    (void)c, (void)s, (void)value;
    return fmi2Discard;
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    Instance *inst = as_instance(c);
    if (s != fmi2LastSuccessfulTime) return fmi2Discard;
    *value = inst->s.time;
    return fmi2OK;
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value) {
    (void)c, (void)s, (void)value;
    return fmi2Discard;
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value) {
    if (s != fmi2Terminated) return fmi2Discard;
    *value = as_instance(c)->s.terminated ? fmi2True : fmi2False;
    return fmi2OK;
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
    (void)c, (void)s, (void)value;
    return fmi2Discard;
}
