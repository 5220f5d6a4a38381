/* The FMI 2.0 model-exchange API around a small model, shared by cosimstep's ME test FMUs.
 *
 * Include once, after the model has defined (all static):
 *   MODEL_GUID, N_VR, N_STATES, N_INDICATORS, CAN_GET_SET_STATE (0 or 1)
 *   typedef struct { double time; double v[N_VR]; ...discrete state... } State;
 *   STATE_VR[N_STATES]              value references of the continuous states
 *   void model_start(State *)       start values
 *   int model_settable(fmi2ValueReference vr, int before_initialization_ends, int in_event_mode)
 *   const char *model_check(const State *)       NULL, or why the parameters are invalid
 *   void model_derivatives(State *s, double dx[N_STATES])  also stores derived variables in v
 *   void model_indicators(const State *s, double z[])      (N_INDICATORS values)
 *   void model_event(State *s, fmi2EventInfo *info)        discrete update at an event; it sets
 *                                    newDiscreteStatesNeeded, valuesOfContinuousStatesChanged
 *                                    and the next time event
 * Every value read is refreshed with model_derivatives first, so derived variables are current.
 */
#ifndef COSIMSTEP_FMI2_ME_FRAME_H
#define COSIMSTEP_FMI2_ME_FRAME_H

#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "fmi2me.h"

#define STATE_MAGIC 0x454d5343u /* "CSME": tags serialized states */

typedef enum {
    MODE_INSTANTIATED, MODE_INITIALIZATION, MODE_EVENT, MODE_CONTINUOUS, MODE_TERMINATED
} Mode;

typedef struct {
    State s;
    Mode mode;
    fmi2CallbackFunctions cb;
    char *name;
    fmi2Boolean logging;
} Instance;

static void log_status(const Instance *inst, fmi2Status status, const char *fmt, ...) {
    char text[512];
    va_list args;
    if (!inst->cb.logger || (status == fmi2OK && !inst->logging)) return;
    va_start(args, fmt);
    vsnprintf(text, sizeof text, fmt, args);
    va_end(args);
    inst->cb.logger(inst->cb.componentEnvironment, inst->name, status,
                    status == fmi2OK ? "logAll" : "logStatusError", "%s", text);
}

#define FAIL(inst, ...) (log_status((inst), fmi2Error, __VA_ARGS__), fmi2Error)

static Instance *as_instance(fmi2Component c) { return (Instance *)c; }

/* ---- common functions ------------------------------------------------------------------- */

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
    Instance *inst;
    size_t n;
    (void)fmuResourceLocation;
    (void)visible;
    if (!functions || !functions->allocateMemory || !functions->freeMemory) return NULL;
    inst = functions->allocateMemory(1, sizeof(Instance));
    if (!inst) return NULL;
    inst->cb = *functions;
    inst->logging = loggingOn;
    n = instanceName ? strlen(instanceName) : 0;
    inst->name = functions->allocateMemory(n + 1, 1);
    if (!inst->name) {
        functions->freeMemory(inst);
        return NULL;
    }
    if (n) memcpy(inst->name, instanceName, n);
    if (fmuType != fmi2ModelExchange) {
        log_status(inst, fmi2Error, "this FMU supports model exchange only");
    } else if (!fmuGUID || strcmp(fmuGUID, MODEL_GUID) != 0) {
        log_status(inst, fmi2Error, "GUID %s does not match %s", fmuGUID ? fmuGUID : "(null)",
                   MODEL_GUID);
    } else {
        model_start(&inst->s);
        inst->mode = MODE_INSTANTIATED;
        return inst;
    }
    functions->freeMemory(inst->name);
    functions->freeMemory(inst);
    return NULL;
}

void fmi2FreeInstance(fmi2Component c) {
    Instance *inst = as_instance(c);
    if (!inst) return;
    inst->cb.freeMemory(inst->name);
    inst->cb.freeMemory(inst);
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined,
                               fmi2Real stopTime) {
    Instance *inst = as_instance(c);
    (void)toleranceDefined;
    (void)tolerance;
    (void)stopTimeDefined;
    (void)stopTime;
    if (inst->mode != MODE_INSTANTIATED)
        return FAIL(inst, "fmi2SetupExperiment is only allowed after fmi2Instantiate");
    inst->s.time = startTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    Instance *inst = as_instance(c);
    if (inst->mode != MODE_INSTANTIATED)
        return FAIL(inst, "fmi2EnterInitializationMode is only allowed after fmi2Instantiate");
    inst->mode = MODE_INITIALIZATION;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    Instance *inst = as_instance(c);
    const char *problem;
    if (inst->mode != MODE_INITIALIZATION)
        return FAIL(inst, "fmi2ExitInitializationMode outside initialization mode");
    problem = model_check(&inst->s);
    if (problem) return FAIL(inst, "%s", problem);
    inst->mode = MODE_EVENT;
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component c) {
    as_instance(c)->mode = MODE_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component c) {
    Instance *inst = as_instance(c);
    memset(&inst->s, 0, sizeof inst->s);
    model_start(&inst->s);
    inst->mode = MODE_INSTANTIATED;
    return fmi2OK;
}

/* ---- getting and setting values --------------------------------------------------------- */

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       fmi2Real value[]) {
    Instance *inst = as_instance(c);
    double dx[N_STATES];
    model_derivatives(&inst->s, dx);
    for (size_t i = 0; i < nvr; i++) {
        if (vr[i] >= N_VR) return FAIL(inst, "fmi2GetReal: unknown value reference %u", vr[i]);
        value[i] = inst->s.v[vr[i]];
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       const fmi2Real value[]) {
    Instance *inst = as_instance(c);
    const int before = inst->mode == MODE_INSTANTIATED || inst->mode == MODE_INITIALIZATION;
    for (size_t i = 0; i < nvr; i++) {
        if (vr[i] >= N_VR) return FAIL(inst, "fmi2SetReal: unknown value reference %u", vr[i]);
        if (!model_settable(vr[i], before, inst->mode == MODE_EVENT))
            return FAIL(inst, "fmi2SetReal: value reference %u cannot be set now", vr[i]);
    }
    for (size_t i = 0; i < nvr; i++) inst->s.v[vr[i]] = value[i];
    return fmi2OK;
}

#define REALS_ONLY_FAIL(c, msg) FAIL(as_instance(c), msg)
#include "fmi2_reals_only.h"

/* ---- FMU state ---------------------------------------------------------------------------- */

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    Instance *inst = as_instance(c);
    State *copy = *FMUstate; /* an earlier state is overwritten in place */
    if (!CAN_GET_SET_STATE) return FAIL(inst, "fmi2GetFMUstate is not provided");
    if (!copy) {
        copy = inst->cb.allocateMemory(1, sizeof(State));
        if (!copy) return FAIL(inst, "fmi2GetFMUstate: out of memory");
    }
    *copy = inst->s;
    *FMUstate = copy;
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    Instance *inst = as_instance(c);
    if (!CAN_GET_SET_STATE) return FAIL(inst, "fmi2SetFMUstate is not provided");
    if (!FMUstate) return FAIL(inst, "fmi2SetFMUstate: no state given");
    inst->s = *(const State *)FMUstate;
    return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    if (FMUstate && *FMUstate) {
        as_instance(c)->cb.freeMemory(*FMUstate);
        *FMUstate = NULL;
    }
    return fmi2OK;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size) {
    (void)FMUstate;
    if (!CAN_GET_SET_STATE) return FAIL(as_instance(c), "FMU state is not provided");
    *size = sizeof(unsigned int) + sizeof(State);
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate,
                                 fmi2Byte serializedState[], size_t size) {
    const unsigned int magic = STATE_MAGIC;
    if (!CAN_GET_SET_STATE) return FAIL(as_instance(c), "FMU state is not provided");
    if (size != sizeof magic + sizeof(State))
        return FAIL(as_instance(c), "fmi2SerializeFMUstate: buffer has %zu bytes, need %zu",
                    size, sizeof magic + sizeof(State));
    memcpy(serializedState, &magic, sizeof magic);
    memcpy(serializedState + sizeof magic, FMUstate, sizeof(State));
    return fmi2OK;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[],
                                   size_t size, fmi2FMUstate *FMUstate) {
    Instance *inst = as_instance(c);
    unsigned int magic;
    if (!CAN_GET_SET_STATE) return FAIL(inst, "FMU state is not provided");
    if (size != sizeof magic + sizeof(State))
        return FAIL(inst, "fmi2DeSerializeFMUstate: %zu bytes is not a state of this FMU", size);
    memcpy(&magic, serializedState, sizeof magic);
    if (magic != STATE_MAGIC)
        return FAIL(inst, "fmi2DeSerializeFMUstate: bytes are not a state of this FMU");
    if (!*FMUstate) {
        *FMUstate = inst->cb.allocateMemory(1, sizeof(State));
        if (!*FMUstate) return FAIL(inst, "fmi2DeSerializeFMUstate: out of memory");
    }
    memcpy(*FMUstate, serializedState + sizeof magic, sizeof(State));
    return fmi2OK;
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[],
                                        size_t nUnknown, const fmi2ValueReference vKnown_ref[],
                                        size_t nKnown, const fmi2Real dvKnown[],
                                        fmi2Real dvUnknown[]) {
    (void)vUnknown_ref;
    (void)nUnknown;
    (void)vKnown_ref;
    (void)nKnown;
    (void)dvKnown;
    (void)dvUnknown;
    return FAIL(as_instance(c), "fmi2GetDirectionalDerivative is not provided");
}

/* ---- model exchange ----------------------------------------------------------------------- */

fmi2Status fmi2EnterEventMode(fmi2Component c) {
    Instance *inst = as_instance(c);
    if (inst->mode != MODE_CONTINUOUS && inst->mode != MODE_EVENT)
        return FAIL(inst, "fmi2EnterEventMode outside continuous-time mode");
    inst->mode = MODE_EVENT;
    return fmi2OK;
}

fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *info) {
    Instance *inst = as_instance(c);
    if (inst->mode != MODE_EVENT) return FAIL(inst, "fmi2NewDiscreteStates outside event mode");
    memset(info, 0, sizeof *info);
    model_event(&inst->s, info);
    return fmi2OK;
}

fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) {
    Instance *inst = as_instance(c);
    if (inst->mode != MODE_EVENT) return FAIL(inst, "fmi2EnterContinuousTimeMode outside event mode");
    inst->mode = MODE_CONTINUOUS;
    return fmi2OK;
}

fmi2Status fmi2CompletedIntegratorStep(fmi2Component c,
                                       fmi2Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi2Boolean *enterEventMode,
                                       fmi2Boolean *terminateSimulation) {
    Instance *inst = as_instance(c);
    (void)noSetFMUStatePriorToCurrentPoint;
    if (inst->mode != MODE_CONTINUOUS)
        return FAIL(inst, "fmi2CompletedIntegratorStep outside continuous-time mode");
    *enterEventMode = fmi2False;
    *terminateSimulation = fmi2False;
    return fmi2OK;
}

fmi2Status fmi2SetTime(fmi2Component c, fmi2Real time) {
    as_instance(c)->s.time = time;
    return fmi2OK;
}

fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t nx) {
    Instance *inst = as_instance(c);
    if (nx != N_STATES) return FAIL(inst, "fmi2SetContinuousStates: %zu states, not %d", nx,
                                    N_STATES);
    for (size_t i = 0; i < nx; i++) inst->s.v[STATE_VR[i]] = x[i];
    return fmi2OK;
}

fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t nx) {
    Instance *inst = as_instance(c);
    if (nx != N_STATES) return FAIL(inst, "fmi2GetContinuousStates: %zu states, not %d", nx,
                                    N_STATES);
    for (size_t i = 0; i < nx; i++) x[i] = inst->s.v[STATE_VR[i]];
    return fmi2OK;
}

fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real derivatives[], size_t nx) {
    Instance *inst = as_instance(c);
    double dx[N_STATES];
    if (nx != N_STATES) return FAIL(inst, "fmi2GetDerivatives: %zu states, not %d", nx,
                                    N_STATES);
    model_derivatives(&inst->s, dx);
    for (size_t i = 0; i < nx; i++) derivatives[i] = dx[i];
    return fmi2OK;
}

fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real eventIndicators[], size_t ni) {
    Instance *inst = as_instance(c);
    if (ni != N_INDICATORS)
        return FAIL(inst, "fmi2GetEventIndicators: %zu indicators, not %d", ni, N_INDICATORS);
    if (ni) model_indicators(&inst->s, eventIndicators);
    return fmi2OK;
}

fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x_nominal[], size_t nx) {
    (void)c;
    for (size_t i = 0; i < nx; i++) x_nominal[i] = 1.0;
    return fmi2OK;
}

#endif /* COSIMSTEP_FMI2_ME_FRAME_H */
