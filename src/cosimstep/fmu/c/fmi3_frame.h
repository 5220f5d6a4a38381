/* The FMI 3.0 API around a small model, shared by cosimstep's FMI 3.0 test FMUs: model exchange,
 * and optionally co-simulation (a fixed-step RK4 of the same equations, inputs held over a step).
 *
 * Co-simulation events: after every internal step the event indicators are compared with the
 * previous ones; a change of sign is an event at the end of that internal step. Without event
 * mode the FMU updates itself there (model_event) and goes on; with eventModeUsed it reports
 * eventHandlingNeeded, returns early at that time if earlyReturnAllowed (else it finishes the
 * step and the importer's event mode comes at its end), and the importer calls
 * fmi3UpdateDiscreteStates in event mode.
 *
 * Include once, after the model has included fmi3_model.h and defined (all static):
 *   MODEL_TOKEN, N_VR (value references 0 .. N_VR - 1), N_V (doubles in State.v),
 *   N_STATES, N_INDICATORS, X_OFFSET (the states are v[X_OFFSET .. X_OFFSET + N_STATES - 1]),
 *   HAS_MODEL_EXCHANGE and HAS_CO_SIMULATION (0 or 1); with co-simulation, MAX_DT_OFFSET (the
 *   index in v of the largest internal RK4 step).
 *   VARS[N_VR]: each value reference's type, offset in v, element count and kind (Var below);
 *               value reference 0 is the independent variable time.
 *   void model_start(State *)                    start values
 *   const char *model_check(const State *)       NULL, or why the parameters are invalid
 *   void model_derivatives(State *s, double dx[N_STATES])  also stores derived variables in v
 *   void model_indicators(const State *s, double z[])      (N_INDICATORS values)
 *   void model_event(State *s, Event *e)         discrete update at an event
 * Integers and booleans are kept in v as doubles; Binary variables (N_BINARY > 0) in State.bin.
 * Every value read is refreshed with model_derivatives first, so derived variables are current.
 */
#ifndef COSIMSTEP_FMI3_FRAME_H
#define COSIMSTEP_FMI3_FRAME_H

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi3_model.h"

#define STATE_MAGIC 0x33464d43u /* "CMF3": tags serialized states */

#ifndef N_BINARY
#define N_BINARY 0
#endif

typedef enum {
    MODE_INSTANTIATED, MODE_INITIALIZATION, MODE_EVENT, MODE_CONTINUOUS, MODE_STEP,
    MODE_TERMINATED
} Mode;

typedef struct {
    State s;
    Mode mode;
    int co_simulation;
    int event_mode_used;       /* co-simulation: the importer handles events in event mode */
    int early_return_allowed;  /* co-simulation: a step may end at an event */
    int terminate;             /* an event asked to end the simulation */
    double prez[N_INDICATORS > 0 ? N_INDICATORS : 1]; /* indicators after the last step */
    fmi3LogMessageCallback log;
    fmi3InstanceEnvironment env;
    fmi3Boolean logging;
} Instance;

static void log_status(const Instance *inst, fmi3Status status, const char *fmt, ...) {
    char text[512];
    va_list args;
    if (!inst->log || (status == fmi3OK && !inst->logging)) return;
    va_start(args, fmt);
    vsnprintf(text, sizeof text, fmt, args);
    va_end(args);
    inst->log(inst->env, status, status == fmi3OK ? "logEvents" : "logStatusError", text);
}

#define FAIL(inst, ...) (log_status((inst), fmi3Error, __VA_ARGS__), fmi3Error)
#define AS(instance) ((Instance *)(instance))

#if HAS_CO_SIMULATION
static void update_inside(Instance *inst);
#endif

/* ---- instances and modes ------------------------------------------------------------------ */

const char *fmi3GetVersion(void) { return fmi3Version; }

fmi3Status fmi3SetDebugLogging(fmi3Instance instance, fmi3Boolean loggingOn, size_t nCategories,
                               const fmi3String categories[]) {
    (void)nCategories;
    (void)categories;
    AS(instance)->logging = loggingOn;
    return fmi3OK;
}

static fmi3Instance instantiate(fmi3String token, fmi3Boolean loggingOn,
                                fmi3InstanceEnvironment env, fmi3LogMessageCallback log,
                                int co_simulation) {
    Instance *inst = calloc(1, sizeof(Instance));
    if (!inst) return NULL;
    inst->log = log;
    inst->env = env;
    inst->logging = loggingOn;
    inst->co_simulation = co_simulation;
    if (!token || strcmp(token, MODEL_TOKEN) != 0) {
        log_status(inst, fmi3Error, "instantiation token %s does not match %s",
                   token ? token : "(null)", MODEL_TOKEN);
        free(inst);
        return NULL;
    }
    model_start(&inst->s);
    inst->mode = MODE_INSTANTIATED;
    return inst;
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible,
                                          fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage) {
    (void)instanceName;
    (void)resourcePath;
    (void)visible;
    if (!HAS_MODEL_EXCHANGE) return NULL;
    return instantiate(instantiationToken, loggingOn, instanceEnvironment, logMessage, 0);
}

fmi3Instance fmi3InstantiateCoSimulation(
    fmi3String instanceName, fmi3String instantiationToken, fmi3String resourcePath,
    fmi3Boolean visible, fmi3Boolean loggingOn, fmi3Boolean eventModeUsed,
    fmi3Boolean earlyReturnAllowed, const fmi3ValueReference requiredIntermediateVariables[],
    size_t nRequiredIntermediateVariables, fmi3InstanceEnvironment instanceEnvironment,
    fmi3LogMessageCallback logMessage, fmi3IntermediateUpdateCallback intermediateUpdate) {
    (void)instanceName;
    (void)resourcePath;
    (void)visible;
    Instance *inst;
    (void)requiredIntermediateVariables;
    (void)nRequiredIntermediateVariables;
    (void)intermediateUpdate;
    if (!HAS_CO_SIMULATION) return NULL;
    inst = instantiate(instantiationToken, loggingOn, instanceEnvironment, logMessage, 1);
    if (inst) {
        inst->event_mode_used = eventModeUsed;
        inst->early_return_allowed = eventModeUsed && earlyReturnAllowed;
    }
    return inst;
}

fmi3Instance fmi3InstantiateScheduledExecution(
    fmi3String instanceName, fmi3String instantiationToken, fmi3String resourcePath,
    fmi3Boolean visible, fmi3Boolean loggingOn, fmi3InstanceEnvironment instanceEnvironment,
    fmi3LogMessageCallback logMessage, fmi3ClockUpdateCallback clockUpdate,
    fmi3LockPreemptionCallback lockPreemption, fmi3UnlockPreemptionCallback unlockPreemption) {
    (void)instanceName;
    (void)instantiationToken;
    (void)resourcePath;
    (void)visible;
    (void)loggingOn;
    (void)instanceEnvironment;
    (void)logMessage;
    (void)clockUpdate;
    (void)lockPreemption;
    (void)unlockPreemption;
    return NULL;
}

void fmi3FreeInstance(fmi3Instance instance) { free(instance); }

fmi3Status fmi3EnterInitializationMode(fmi3Instance instance, fmi3Boolean toleranceDefined,
                                       fmi3Float64 tolerance, fmi3Float64 startTime,
                                       fmi3Boolean stopTimeDefined, fmi3Float64 stopTime) {
    Instance *inst = AS(instance);
    (void)toleranceDefined;
    (void)tolerance;
    (void)stopTimeDefined;
    (void)stopTime;
    if (inst->mode != MODE_INSTANTIATED)
        return FAIL(inst, "fmi3EnterInitializationMode is only allowed after instantiation");
    inst->s.time = startTime;
    inst->mode = MODE_INITIALIZATION;
    return fmi3OK;
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance instance) {
    Instance *inst = AS(instance);
    const char *problem;
    if (inst->mode != MODE_INITIALIZATION)
        return FAIL(inst, "fmi3ExitInitializationMode outside initialization mode");
    problem = model_check(&inst->s);
    if (problem) return FAIL(inst, "%s", problem);
    /* model exchange, and co-simulation with event mode, continue in event mode */
    inst->mode = inst->co_simulation && !inst->event_mode_used ? MODE_STEP : MODE_EVENT;
#if HAS_CO_SIMULATION
    if (inst->mode == MODE_STEP) update_inside(inst); /* the initial event, done by the FMU */
#endif
    return fmi3OK;
}

fmi3Status fmi3EnterEventMode(fmi3Instance instance) {
    Instance *inst = AS(instance);
    if (inst->co_simulation && !inst->event_mode_used)
        return FAIL(inst, "fmi3EnterEventMode: instantiated without eventModeUsed");
    if (inst->mode != MODE_CONTINUOUS && inst->mode != MODE_EVENT && inst->mode != MODE_STEP)
        return FAIL(inst, "fmi3EnterEventMode outside continuous-time or step mode");
    inst->mode = MODE_EVENT;
    return fmi3OK;
}

fmi3Status fmi3Terminate(fmi3Instance instance) {
    AS(instance)->mode = MODE_TERMINATED;
    return fmi3OK;
}

fmi3Status fmi3Reset(fmi3Instance instance) {
    Instance *inst = AS(instance);
    memset(&inst->s, 0, sizeof inst->s);
    model_start(&inst->s);
    inst->mode = MODE_INSTANTIATED;
    return fmi3OK;
}

/* ---- getting and setting values ----------------------------------------------------------- */

/* Whether value reference vr may be set in the instance's current mode. */
static int settable(const Instance *inst, fmi3ValueReference vr) {
    const int before = inst->mode == MODE_INSTANTIATED || inst->mode == MODE_INITIALIZATION;
    switch (VARS[vr].kind) {
    case K_PARAMETER:
    case K_STATE:
        return before;
    case K_INPUT:
        return inst->mode != MODE_TERMINATED;
    case K_DISCRETE_INPUT:
        return before || inst->mode == MODE_EVENT || inst->mode == MODE_STEP;
    default:
        return 0;
    }
}

/* Check value references and the element count against the expected type; 0 when fine. */
static int check_values(Instance *inst, const char *call, VarType type,
                        const fmi3ValueReference vr[], size_t nvr, size_t nValues, int set) {
    size_t count = 0;
    for (size_t i = 0; i < nvr; i++) {
        if (vr[i] >= N_VR || VARS[vr[i]].type != type) {
            log_status(inst, fmi3Error, "%s: value reference %u is not a variable of this type",
                       call, vr[i]);
            return -1;
        }
        if (set && !settable(inst, vr[i])) {
            log_status(inst, fmi3Error, "%s: value reference %u cannot be set now", call, vr[i]);
            return -1;
        }
        count += VARS[vr[i]].size;
    }
    if (count != nValues) {
        log_status(inst, fmi3Error, "%s: %zu values given for %zu", call, nValues, count);
        return -1;
    }
    return 0;
}

static void refresh(Instance *inst) {
    double dx[N_STATES > 0 ? N_STATES : 1];
    model_derivatives(&inst->s, dx);
}

#define GETSET(Name, Type, VT, TO_DOUBLE, FROM_DOUBLE)                                          \
    fmi3Status fmi3Get##Name(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,  \
                             Type values[], size_t nValues) {                                   \
        Instance *inst = AS(instance);                                                          \
        size_t k = 0;                                                                           \
        if (check_values(inst, "fmi3Get" #Name, VT, vr, nvr, nValues, 0)) return fmi3Error;     \
        refresh(inst);                                                                          \
        for (size_t i = 0; i < nvr; i++) {                                                      \
            const double *from = vr[i] == 0 ? &inst->s.time : &inst->s.v[VARS[vr[i]].offset];   \
            for (int j = 0; j < VARS[vr[i]].size; j++) values[k++] = FROM_DOUBLE(from[j]);      \
        }                                                                                       \
        return fmi3OK;                                                                          \
    }                                                                                           \
    fmi3Status fmi3Set##Name(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,  \
                             const Type values[], size_t nValues) {                             \
        Instance *inst = AS(instance);                                                          \
        size_t k = 0;                                                                           \
        if (check_values(inst, "fmi3Set" #Name, VT, vr, nvr, nValues, 1)) return fmi3Error;     \
        for (size_t i = 0; i < nvr; i++)                                                        \
            for (int j = 0; j < VARS[vr[i]].size; j++)                                          \
                inst->s.v[VARS[vr[i]].offset + j] = TO_DOUBLE(values[k++]);                     \
        return fmi3OK;                                                                          \
    }

#define SAME(x) (x)
#define AS_BOOL(x) ((x) != 0.0)
#define AS_INT32(x) ((fmi3Int32)(x))
#define BOOL_TO_DOUBLE(x) ((x) ? 1.0 : 0.0)
GETSET(Float64, fmi3Float64, T_FLOAT64, SAME, SAME)
GETSET(Int32, fmi3Int32, T_INT32, (double), AS_INT32)
GETSET(Boolean, fmi3Boolean, T_BOOLEAN, BOOL_TO_DOUBLE, AS_BOOL)

/* Types this frame has no variables of: every call with value references fails. */
#define NO_VARIABLES(Name, Type)                                                               \
    fmi3Status fmi3Get##Name(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,  \
                             Type values[], size_t nValues) {                                   \
        (void)vr;                                                                               \
        (void)values;                                                                           \
        (void)nValues;                                                                          \
        return nvr ? FAIL(AS(instance), "fmi3Get" #Name ": no variables of this type")          \
                   : fmi3OK;                                                                    \
    }                                                                                           \
    fmi3Status fmi3Set##Name(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,  \
                             const Type values[], size_t nValues) {                             \
        (void)vr;                                                                               \
        (void)values;                                                                           \
        (void)nValues;                                                                          \
        return nvr ? FAIL(AS(instance), "fmi3Set" #Name ": no variables of this type")          \
                   : fmi3OK;                                                                    \
    }
NO_VARIABLES(Float32, fmi3Float32)
NO_VARIABLES(Int8, fmi3Int8)
NO_VARIABLES(UInt8, fmi3UInt8)
NO_VARIABLES(Int16, fmi3Int16)
NO_VARIABLES(UInt16, fmi3UInt16)
NO_VARIABLES(UInt32, fmi3UInt32)
NO_VARIABLES(Int64, fmi3Int64)
NO_VARIABLES(UInt64, fmi3UInt64)
NO_VARIABLES(String, fmi3String)

#if N_BINARY > 0
/* The pointers stay valid until the value is set again (the standard's requirement). */
fmi3Status fmi3GetBinary(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                         size_t valueSizes[], fmi3Binary values[], size_t nValues) {
    Instance *inst = AS(instance);
    if (check_values(inst, "fmi3GetBinary", T_BINARY, vr, nvr, nValues, 0)) return fmi3Error;
    refresh(inst);
    for (size_t i = 0; i < nvr; i++) {
        const int k = VARS[vr[i]].offset;
        values[i] = inst->s.bin[k];
        valueSizes[i] = inst->s.bin_size[k];
    }
    return fmi3OK;
}

fmi3Status fmi3SetBinary(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                         const size_t valueSizes[], const fmi3Binary values[], size_t nValues) {
    Instance *inst = AS(instance);
    if (check_values(inst, "fmi3SetBinary", T_BINARY, vr, nvr, nValues, 1)) return fmi3Error;
    for (size_t i = 0; i < nvr; i++)
        if (valueSizes[i] > BINARY_MAX)
            return FAIL(inst, "fmi3SetBinary: %zu bytes, at most %d", valueSizes[i], BINARY_MAX);
    for (size_t i = 0; i < nvr; i++) {
        const int k = VARS[vr[i]].offset;
        if (valueSizes[i]) memcpy(inst->s.bin[k], values[i], valueSizes[i]);
        inst->s.bin_size[k] = valueSizes[i];
    }
    return fmi3OK;
}
#else
fmi3Status fmi3GetBinary(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                         size_t valueSizes[], fmi3Binary values[], size_t nValues) {
    (void)vr;
    (void)valueSizes;
    (void)values;
    (void)nValues;
    return nvr ? FAIL(AS(instance), "fmi3GetBinary: no variables of this type") : fmi3OK;
}

fmi3Status fmi3SetBinary(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                         const size_t valueSizes[], const fmi3Binary values[], size_t nValues) {
    (void)vr;
    (void)valueSizes;
    (void)values;
    (void)nValues;
    return nvr ? FAIL(AS(instance), "fmi3SetBinary: no variables of this type") : fmi3OK;
}
#endif

/* ---- what this frame does not provide ----------------------------------------------------- */

#define NOT_PROVIDED(call) return FAIL(AS(instance), call " is not provided by this FMU")

#define UNSUPPORTED(call) NOT_PROVIDED(call)
#include "fmi3_unsupported.h"

fmi3Status fmi3GetOutputDerivatives(fmi3Instance instance, const fmi3ValueReference vr[],
                                    size_t nvr, const fmi3Int32 orders[], fmi3Float64 values[],
                                    size_t nValues) {
    (void)vr; (void)nvr; (void)orders; (void)values; (void)nValues;
    NOT_PROVIDED("fmi3GetOutputDerivatives");
}

/* ---- FMU state ---------------------------------------------------------------------------- */

/* An FMU state is an Instance of which the model state, the mode, a pending termination and the
 * last event indicators (co-simulation) are used; serialized, those four in this order. */
#define PREZ_BYTES sizeof(((Instance *)0)->prez)
#define SAVED_BYTES (sizeof(State) + sizeof(Mode) + sizeof(int) + PREZ_BYTES)

static void copy_saved(Instance *to, const Instance *from) {
    to->s = from->s;
    to->mode = from->mode;
    to->terminate = from->terminate;
    memcpy(to->prez, from->prez, PREZ_BYTES);
}

fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    Instance *inst = AS(instance);
    Instance *copy = *FMUState; /* an earlier state is overwritten in place */
    if (!copy) {
        copy = calloc(1, sizeof(Instance));
        if (!copy) return FAIL(inst, "fmi3GetFMUState: out of memory");
    }
    copy_saved(copy, inst);
    *FMUState = copy;
    return fmi3OK;
}

fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState FMUState) {
    Instance *inst = AS(instance);
    if (!FMUState) return FAIL(inst, "fmi3SetFMUState: no state given");
    copy_saved(inst, FMUState);
    return fmi3OK;
}

fmi3Status fmi3FreeFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    (void)instance;
    if (FMUState && *FMUState) {
        free(*FMUState);
        *FMUState = NULL;
    }
    return fmi3OK;
}

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance instance, fmi3FMUState FMUState,
                                      size_t *size) {
    (void)instance;
    (void)FMUState;
    *size = sizeof(unsigned int) + SAVED_BYTES;
    return fmi3OK;
}

fmi3Status fmi3SerializeFMUState(fmi3Instance instance, fmi3FMUState FMUState,
                                 fmi3Byte serialized[], size_t size) {
    const unsigned int magic = STATE_MAGIC;
    const Instance *saved = FMUState;
    fmi3Byte *at = serialized;
    if (size != sizeof magic + SAVED_BYTES)
        return FAIL(AS(instance), "fmi3SerializeFMUState: buffer of %zu bytes", size);
    memcpy(at, &magic, sizeof magic);
    memcpy(at += sizeof magic, &saved->s, sizeof(State));
    memcpy(at += sizeof(State), &saved->mode, sizeof(Mode));
    memcpy(at += sizeof(Mode), &saved->terminate, sizeof(int));
    memcpy(at + sizeof(int), saved->prez, PREZ_BYTES);
    return fmi3OK;
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance instance, const fmi3Byte serialized[],
                                   size_t size, fmi3FMUState *FMUState) {
    Instance *inst = AS(instance);
    Instance *copy = *FMUState;
    const fmi3Byte *at = serialized;
    unsigned int magic;
    if (size != sizeof magic + SAVED_BYTES)
        return FAIL(inst, "fmi3DeserializeFMUState: %zu bytes is not a state of this FMU", size);
    memcpy(&magic, at, sizeof magic);
    if (magic != STATE_MAGIC)
        return FAIL(inst, "fmi3DeserializeFMUState: bytes are not a state of this FMU");
    if (!copy) {
        copy = calloc(1, sizeof(Instance));
        if (!copy) return FAIL(inst, "fmi3DeserializeFMUState: out of memory");
    }
    memcpy(&copy->s, at += sizeof magic, sizeof(State));
    memcpy(&copy->mode, at += sizeof(State), sizeof(Mode));
    memcpy(&copy->terminate, at += sizeof(Mode), sizeof(int));
    memcpy(copy->prez, at + sizeof(int), PREZ_BYTES);
    *FMUState = copy;
    return fmi3OK;
}

/* ---- events (model exchange) -------------------------------------------------------------- */

fmi3Status fmi3UpdateDiscreteStates(fmi3Instance instance, fmi3Boolean *discreteStatesNeedUpdate,
                                    fmi3Boolean *terminateSimulation,
                                    fmi3Boolean *nominalsOfContinuousStatesChanged,
                                    fmi3Boolean *valuesOfContinuousStatesChanged,
                                    fmi3Boolean *nextEventTimeDefined,
                                    fmi3Float64 *nextEventTime) {
    Instance *inst = AS(instance);
    Event e = {0, 0, 0, 0.0};
    if (inst->mode != MODE_EVENT) return FAIL(inst, "fmi3UpdateDiscreteStates outside event mode");
    refresh(inst);
    model_event(&inst->s, &e);
#if HAS_CO_SIMULATION && N_INDICATORS > 0
    if (inst->co_simulation) { /* the indicators after the update are the new reference */
        double z[N_INDICATORS];
        refresh(inst);
        model_indicators(&inst->s, z);
        memcpy(inst->prez, z, sizeof z);
    }
#endif
    *discreteStatesNeedUpdate = fmi3False;
    *terminateSimulation = e.terminate != 0;
    *nominalsOfContinuousStatesChanged = fmi3False;
    *valuesOfContinuousStatesChanged = e.values_changed != 0;
    *nextEventTimeDefined = e.time_defined != 0;
    *nextEventTime = e.next_time;
    if (e.terminate) log_status(inst, fmi3OK, "terminateSimulation at t = %g", inst->s.time);
    return fmi3OK;
}

fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance instance) {
    Instance *inst = AS(instance);
    if (inst->mode != MODE_EVENT || inst->co_simulation)
        return FAIL(inst, "fmi3EnterContinuousTimeMode outside event mode of model exchange");
    inst->mode = MODE_CONTINUOUS;
    return fmi3OK;
}

fmi3Status fmi3CompletedIntegratorStep(fmi3Instance instance,
                                       fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean *enterEventMode,
                                       fmi3Boolean *terminateSimulation) {
    Instance *inst = AS(instance);
    (void)noSetFMUStatePriorToCurrentPoint;
    if (inst->mode != MODE_CONTINUOUS)
        return FAIL(inst, "fmi3CompletedIntegratorStep outside continuous-time mode");
    *enterEventMode = fmi3False;
    *terminateSimulation = fmi3False;
    return fmi3OK;
}

fmi3Status fmi3SetTime(fmi3Instance instance, fmi3Float64 time) {
    AS(instance)->s.time = time;
    return fmi3OK;
}

fmi3Status fmi3SetContinuousStates(fmi3Instance instance, const fmi3Float64 x[], size_t nx) {
    Instance *inst = AS(instance);
    if (nx != N_STATES)
        return FAIL(inst, "fmi3SetContinuousStates: %zu states, not %d", nx, N_STATES);
    for (size_t i = 0; i < nx; i++) inst->s.v[X_OFFSET + i] = x[i];
    return fmi3OK;
}

fmi3Status fmi3GetContinuousStates(fmi3Instance instance, fmi3Float64 x[], size_t nx) {
    Instance *inst = AS(instance);
    if (nx != N_STATES)
        return FAIL(inst, "fmi3GetContinuousStates: %zu states, not %d", nx, N_STATES);
    for (size_t i = 0; i < nx; i++) x[i] = inst->s.v[X_OFFSET + i];
    return fmi3OK;
}

fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance instance, fmi3Float64 dx[],
                                             size_t nx) {
    Instance *inst = AS(instance);
    double d[N_STATES > 0 ? N_STATES : 1];
    if (nx != N_STATES)
        return FAIL(inst, "fmi3GetContinuousStateDerivatives: %zu states, not %d", nx, N_STATES);
    model_derivatives(&inst->s, d);
    for (size_t i = 0; i < nx; i++) dx[i] = d[i];
    return fmi3OK;
}

fmi3Status fmi3GetEventIndicators(fmi3Instance instance, fmi3Float64 z[], size_t nz) {
    Instance *inst = AS(instance);
    if (nz != N_INDICATORS)
        return FAIL(inst, "fmi3GetEventIndicators: %zu indicators, not %d", nz, N_INDICATORS);
    if (nz) {
        refresh(inst);
        model_indicators(&inst->s, z);
    }
    return fmi3OK;
}

fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance instance, fmi3Float64 nominals[],
                                             size_t nx) {
    (void)instance;
    for (size_t i = 0; i < nx; i++) nominals[i] = 1.0;
    return fmi3OK;
}

fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance instance, size_t *n) {
    (void)instance;
    *n = N_INDICATORS;
    return fmi3OK;
}

fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance instance, size_t *n) {
    (void)instance;
    *n = N_STATES;
    return fmi3OK;
}

/* ---- co-simulation ------------------------------------------------------------------------ */

fmi3Status fmi3EnterStepMode(fmi3Instance instance) {
    Instance *inst = AS(instance);
    if (!inst->co_simulation || inst->mode != MODE_EVENT)
        return FAIL(inst, "fmi3EnterStepMode outside event mode of co-simulation");
    inst->mode = MODE_STEP;
    return fmi3OK;
}

#if HAS_CO_SIMULATION
/* One RK4 step from s->time to t_end, inputs held. */
static void rk4(State *s, double t_end) {
    double x0[N_STATES > 0 ? N_STATES : 1], k[4][N_STATES > 0 ? N_STATES : 1];
    const double w[4] = {1.0, 2.0, 2.0, 1.0}, c[4] = {0.0, 0.5, 0.5, 1.0};
    const double ts = s->time, dt = t_end - ts;
    double *x = &s->v[X_OFFSET];
    memcpy(x0, x, sizeof x0);
    for (int stage = 0; stage < 4; stage++) {
        for (int i = 0; i < N_STATES; i++)
            x[i] = x0[i] + (stage ? c[stage] * dt * k[stage - 1][i] : 0.0);
        s->time = ts + c[stage] * dt;
        model_derivatives(s, k[stage]);
    }
    for (int i = 0; i < N_STATES; i++) {
        double sum = 0.0;
        for (int stage = 0; stage < 4; stage++) sum += w[stage] * k[stage][i];
        x[i] = x0[i] + dt / 6.0 * sum;
    }
    s->time = t_end;
}

/* Whether an event indicator changed sign since the last internal step (and remember them). */
static int crossed(Instance *inst) {
    int found = 0;
#if N_INDICATORS > 0
    double z[N_INDICATORS];
    refresh(inst);
    model_indicators(&inst->s, z);
    for (int i = 0; i < N_INDICATORS; i++) {
        /* leaving an indicator of exactly 0 (where an event left it) is not a crossing */
        found |= (inst->prez[i] < 0.0 && z[i] > 0.0) || (inst->prez[i] > 0.0 && z[i] <= 0.0);
        inst->prez[i] = z[i];
    }
#else
    (void)inst;
#endif
    return found;
}

/* The discrete update at an event inside a step (no event mode). */
static void update_inside(Instance *inst) {
    Event e = {0, 0, 0, 0.0};
    refresh(inst);
    model_event(&inst->s, &e);
    inst->terminate = e.terminate;
    (void)crossed(inst); /* the indicators after the update are the new reference */
}
#endif

fmi3Status fmi3DoStep(fmi3Instance instance, fmi3Float64 currentCommunicationPoint,
                      fmi3Float64 communicationStepSize,
                      fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                      fmi3Boolean *eventHandlingNeeded, fmi3Boolean *terminateSimulation,
                      fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime) {
    Instance *inst = AS(instance);
    (void)noSetFMUStatePriorToCurrentPoint;
    if (!inst->co_simulation || inst->mode != MODE_STEP)
        return FAIL(inst, "fmi3DoStep outside step mode");
    if (!(communicationStepSize > 0.0))
        return FAIL(inst, "fmi3DoStep: step size %g is not positive", communicationStepSize);
    inst->s.time = currentCommunicationPoint;
    *eventHandlingNeeded = fmi3False;
    *terminateSimulation = fmi3False;
    *earlyReturn = fmi3False;
#if HAS_CO_SIMULATION
    {
        /* n = ceil(h / max_dt) equal internal steps, inputs held */
        const double t0 = currentCommunicationPoint, h = communicationStepSize;
        const long n = (long)fmax(1.0, ceil(h / inst->s.v[MAX_DT_OFFSET] - 1e-9));
        for (long i = 1; i <= n && !inst->terminate; i++) {
            rk4(&inst->s, i == n ? t0 + h : t0 + (double)i * (h / (double)n));
            if (!crossed(inst)) continue;
            if (!inst->event_mode_used) {
                update_inside(inst);
            } else {
                *eventHandlingNeeded = fmi3True;
                if (inst->early_return_allowed && i < n) {
                    *earlyReturn = fmi3True;
                    break;
                }
            }
        }
    }
#endif
    *terminateSimulation = inst->terminate;
    *lastSuccessfulTime = inst->s.time;
    return fmi3OK;
}

#endif /* COSIMSTEP_FMI3_FRAME_H */
