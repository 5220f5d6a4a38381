/* One bar of the split double pendulum as an FMI 3.0 co-simulation FMU.
 *
 * Compile with -DBAR=1 (upper bar) or -DBAR=2 (lower bar). The bar integrates its own angle theta
 * and angular velocity omega with RK4 (local step at most max_dt, as OdeSubModel with
 * RK4(max_dt)) and receives the other bar's angle and angular velocity as inputs, which it holds
 * constant over a step: FMI 3.0 has no input derivatives. Output derivatives of order 1 come from
 * fmi3GetOutputDerivatives. FMU state get/set/free/serialize supports rollback.
 *
 * Every function of the FMI 3.0 API is exported; those outside co-simulation (model exchange,
 * scheduled execution, clocks, other variable types) log why and return fmi3Error.
 */
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi3.h"
#include "pendulum_physics.h"

/* Largest number of RK4 local steps one communication step may take. */
#define PENDULUM_MAX_SUBSTEPS 100000000.0

/* RK4 over [a, a + h] with n = max(1, ceil(h / max_dt - 1e-9)) equal local steps and inputs
 * held at u, as OdeSubModel with RK4(max_dt) does when no input derivatives are set.
 * Returns 0, or -1 when the step needs more than PENDULUM_MAX_SUBSTEPS local steps. */
static int pendulum_rk4(const PendulumParameters *p, double a, double h, double max_dt,
                        const double u[2], double x[2]) {
    double xs[2], k1[2], k2[2], k3[2], k4[2];
    const double steps = ceil(h / max_dt - 1e-9);
    long n;
    double dt;
    if (!(steps <= PENDULUM_MAX_SUBSTEPS)) return -1;
    n = steps < 1.0 ? 1 : (long)steps;
    dt = h / n;
    (void)a; /* autonomous: the time of a stage does not enter the equations */
    for (long i = 0; i < n; i++) {
        pendulum_rhs(p, x, u, k1);
        for (int j = 0; j < 2; j++) xs[j] = x[j] + 0.5 * dt * k1[j];
        pendulum_rhs(p, xs, u, k2);
        for (int j = 0; j < 2; j++) xs[j] = x[j] + 0.5 * dt * k2[j];
        pendulum_rhs(p, xs, u, k3);
        for (int j = 0; j < 2; j++) xs[j] = x[j] + dt * k3[j];
        pendulum_rhs(p, xs, u, k4);
        for (int j = 0; j < 2; j++)
            x[j] = x[j] + dt / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j]);
    }
    return 0;
}

#if BAR == 1
#define TOKEN "{5d0b7c6e-3a41-4f8e-b2d9-6c1f0e3a9b01}"
#define THETA_START 0.4
#define OTHER_THETA_START (-0.3)
#else
#define TOKEN "{5d0b7c6e-3a41-4f8e-b2d9-6c1f0e3a9b02}"
#define THETA_START (-0.3)
#define OTHER_THETA_START 0.4
#endif

#define STATE_MAGIC 0x33534231u /* "1BS3": tags serialized states */

/* Value references, as in modelDescription.xml (0 is time, the independent variable). */
enum {
    VR_TIME, VR_THETA, VR_OMEGA,    /* outputs: this bar's state */
    VR_U_THETA, VR_U_OMEGA,         /* inputs: the other bar's angle and angular velocity */
    VR_M1, VR_M2, VR_L1, VR_L2, VR_G, VR_MAX_DT, /* parameters */
    N_VR
};

static const double START[N_VR] = {
    0.0, THETA_START, 0.0, OTHER_THETA_START, 0.0, 1.0, 1.0, 1.0, 1.0, 9.81, 1e-3
};

/* Everything a step depends on; fmi3GetFMUState copies exactly this. v[VR_TIME] is the time. */
typedef struct {
    double v[N_VR];
} State;

typedef enum { MODE_INSTANTIATED, MODE_INITIALIZATION, MODE_STEP, MODE_TERMINATED } Mode;

typedef struct {
    State s;
    Mode mode;
    fmi3InstanceEnvironment env;
    fmi3LogMessageCallback log;
    fmi3Boolean logging;
} Instance;

static void log_status(const Instance *inst, fmi3Status status, const char *fmt, ...) {
    char text[512];
    va_list args;
    if (!inst || !inst->log || (status == fmi3OK && !inst->logging)) return;
    va_start(args, fmt);
    vsnprintf(text, sizeof text, fmt, args);
    va_end(args);
    inst->log(inst->env, status, status == fmi3OK ? "logAll" : "logStatusError", text);
}

#define FAIL(inst, ...) (log_status((inst), fmi3Error, __VA_ARGS__), fmi3Error)

static Instance *as_instance(fmi3Instance c) { return (Instance *)c; }

static PendulumParameters parameters(const State *s) {
    PendulumParameters p = {s->v[VR_M1], s->v[VR_M2], s->v[VR_L1], s->v[VR_L2], s->v[VR_G]};
    return p;
}

static int is_input(fmi3ValueReference vr) { return vr == VR_U_THETA || vr == VR_U_OMEGA; }

static int is_parameter(fmi3ValueReference vr) { return vr >= VR_M1 && vr < N_VR; }

/* ---- instantiation and modes -------------------------------------------------------------- */

const char *fmi3GetVersion(void) { return fmi3Version; }

fmi3Status fmi3SetDebugLogging(fmi3Instance instance, fmi3Boolean loggingOn, size_t nCategories,
                               const fmi3String categories[]) {
    (void)nCategories;
    (void)categories;
    as_instance(instance)->logging = loggingOn;
    return fmi3OK;
}

fmi3Instance fmi3InstantiateCoSimulation(
    fmi3String instanceName, fmi3String instantiationToken, fmi3String resourcePath,
    fmi3Boolean visible, fmi3Boolean loggingOn, fmi3Boolean eventModeUsed,
    fmi3Boolean earlyReturnAllowed, const fmi3ValueReference requiredIntermediateVariables[],
    size_t nRequiredIntermediateVariables, fmi3InstanceEnvironment instanceEnvironment,
    fmi3LogMessageCallback logMessage, fmi3IntermediateUpdateCallback intermediateUpdate) {
    Instance probe = {0};
    Instance *inst;
    (void)instanceName;
    (void)resourcePath;
    (void)visible;
    (void)earlyReturnAllowed;
    (void)requiredIntermediateVariables;
    (void)intermediateUpdate;
    probe.env = instanceEnvironment;
    probe.log = logMessage;
    if (!instantiationToken || strcmp(instantiationToken, TOKEN) != 0) {
        log_status(&probe, fmi3Error, "instantiation token %s does not match %s",
                   instantiationToken ? instantiationToken : "(null)", TOKEN);
        return NULL;
    }
    if (eventModeUsed || nRequiredIntermediateVariables) {
        log_status(&probe, fmi3Error, "event mode and intermediate variables are not supported");
        return NULL;
    }
    inst = calloc(1, sizeof(Instance));
    if (!inst) return NULL;
    *inst = probe;
    inst->logging = loggingOn;
    memcpy(inst->s.v, START, sizeof START);
    inst->mode = MODE_INSTANTIATED;
    return inst;
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible,
                                          fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage) {
    Instance probe = {0};
    (void)instanceName;
    (void)instantiationToken;
    (void)resourcePath;
    (void)visible;
    (void)loggingOn;
    probe.env = instanceEnvironment;
    probe.log = logMessage;
    log_status(&probe, fmi3Error, "this FMU supports co-simulation only");
    return NULL;
}

fmi3Instance fmi3InstantiateScheduledExecution(
    fmi3String instanceName, fmi3String instantiationToken, fmi3String resourcePath,
    fmi3Boolean visible, fmi3Boolean loggingOn, fmi3InstanceEnvironment instanceEnvironment,
    fmi3LogMessageCallback logMessage, fmi3ClockUpdateCallback clockUpdate,
    fmi3LockPreemptionCallback lockPreemption, fmi3UnlockPreemptionCallback unlockPreemption) {
    (void)clockUpdate;
    (void)lockPreemption;
    (void)unlockPreemption;
    return fmi3InstantiateModelExchange(instanceName, instantiationToken, resourcePath, visible,
                                        loggingOn, instanceEnvironment, logMessage);
}

void fmi3FreeInstance(fmi3Instance instance) { free(instance); }

fmi3Status fmi3EnterInitializationMode(fmi3Instance instance, fmi3Boolean toleranceDefined,
                                       fmi3Float64 tolerance, fmi3Float64 startTime,
                                       fmi3Boolean stopTimeDefined, fmi3Float64 stopTime) {
    Instance *inst = as_instance(instance);
    (void)toleranceDefined;
    (void)tolerance;
    (void)stopTimeDefined;
    (void)stopTime;
    if (inst->mode != MODE_INSTANTIATED)
        return FAIL(inst, "fmi3EnterInitializationMode is only allowed after instantiation");
    inst->s.v[VR_TIME] = startTime;
    inst->mode = MODE_INITIALIZATION;
    return fmi3OK;
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance instance) {
    Instance *inst = as_instance(instance);
    const double *v = inst->s.v;
    if (inst->mode != MODE_INITIALIZATION)
        return FAIL(inst, "fmi3ExitInitializationMode outside initialization mode");
    if (!(v[VR_MAX_DT] > 0.0))
        return FAIL(inst, "parameter max_dt must be positive, got %g", v[VR_MAX_DT]);
    if (!(v[VR_M1] > 0.0 && v[VR_M2] > 0.0 && v[VR_L1] > 0.0 && v[VR_L2] > 0.0))
        return FAIL(inst, "masses and lengths must be positive");
    inst->mode = MODE_STEP;
    return fmi3OK;
}

fmi3Status fmi3EnterEventMode(fmi3Instance instance) {
    return FAIL(as_instance(instance), "fmi3EnterEventMode: this FMU has no event mode");
}

fmi3Status fmi3Terminate(fmi3Instance instance) {
    as_instance(instance)->mode = MODE_TERMINATED;
    return fmi3OK;
}

fmi3Status fmi3Reset(fmi3Instance instance) {
    Instance *inst = as_instance(instance);
    memcpy(inst->s.v, START, sizeof START);
    inst->mode = MODE_INSTANTIATED;
    return fmi3OK;
}

/* ---- getting and setting values ------------------------------------------------------------ */

fmi3Status fmi3GetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, fmi3Float64 values[], size_t nValues) {
    Instance *inst = as_instance(instance);
    if (nValues != nValueReferences)
        return FAIL(inst, "fmi3GetFloat64: %zu values for %zu scalar variables", nValues,
                    nValueReferences);
    for (size_t i = 0; i < nValueReferences; i++) {
        if (valueReferences[i] >= N_VR)
            return FAIL(inst, "fmi3GetFloat64: unknown value reference %u", valueReferences[i]);
        values[i] = inst->s.v[valueReferences[i]];
    }
    return fmi3OK;
}

fmi3Status fmi3SetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, const fmi3Float64 values[], size_t nValues) {
    Instance *inst = as_instance(instance);
    const int before_step = inst->mode == MODE_INSTANTIATED || inst->mode == MODE_INITIALIZATION;
    if (nValues != nValueReferences)
        return FAIL(inst, "fmi3SetFloat64: %zu values for %zu scalar variables", nValues,
                    nValueReferences);
    for (size_t i = 0; i < nValueReferences; i++) {
        const fmi3ValueReference vr = valueReferences[i];
        if (vr >= N_VR || vr == VR_TIME)
            return FAIL(inst, "fmi3SetFloat64: value reference %u cannot be set", vr);
        if (!(is_input(vr) || (before_step && (is_parameter(vr) || vr == VR_THETA ||
                                               vr == VR_OMEGA))))
            return FAIL(inst, "fmi3SetFloat64: value reference %u can only be set before "
                        "initialization ends", vr);
    }
    for (size_t i = 0; i < nValueReferences; i++) inst->s.v[valueReferences[i]] = values[i];
    return fmi3OK;
}

/* Variable types this FMU does not have: any value reference is an error. */
#define NO_VARIABLES(Name, Type)                                                            \
    fmi3Status fmi3Get##Name(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, \
                             Type values[], size_t nValues) {                               \
        (void)vr;                                                                           \
        (void)values;                                                                       \
        (void)nValues;                                                                      \
        if (nvr) return FAIL(as_instance(instance), "fmi3Get" #Name ": no such variables"); \
        return fmi3OK;                                                                      \
    }                                                                                       \
    fmi3Status fmi3Set##Name(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, \
                             const Type values[], size_t nValues) {                         \
        (void)vr;                                                                           \
        (void)values;                                                                       \
        (void)nValues;                                                                      \
        if (nvr) return FAIL(as_instance(instance), "fmi3Set" #Name ": no such variables"); \
        return fmi3OK;                                                                      \
    }
NO_VARIABLES(Float32, fmi3Float32)
NO_VARIABLES(Int8, fmi3Int8)
NO_VARIABLES(UInt8, fmi3UInt8)
NO_VARIABLES(Int16, fmi3Int16)
NO_VARIABLES(UInt16, fmi3UInt16)
NO_VARIABLES(Int32, fmi3Int32)
NO_VARIABLES(UInt32, fmi3UInt32)
NO_VARIABLES(Int64, fmi3Int64)
NO_VARIABLES(UInt64, fmi3UInt64)
NO_VARIABLES(Boolean, fmi3Boolean)
NO_VARIABLES(String, fmi3String)

fmi3Status fmi3GetBinary(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                         size_t nValueReferences, size_t valueSizes[], fmi3Binary values[],
                         size_t nValues) {
    (void)valueReferences;
    (void)valueSizes;
    (void)values;
    (void)nValues;
    if (nValueReferences) return FAIL(as_instance(instance), "fmi3GetBinary: no such variables");
    return fmi3OK;
}

fmi3Status fmi3SetBinary(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                         size_t nValueReferences, const size_t valueSizes[],
                         const fmi3Binary values[], size_t nValues) {
    (void)valueReferences;
    (void)valueSizes;
    (void)values;
    (void)nValues;
    if (nValueReferences) return FAIL(as_instance(instance), "fmi3SetBinary: no such variables");
    return fmi3OK;
}

/* ---- FMU state ------------------------------------------------------------------------------ */

fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    Instance *inst = as_instance(instance);
    State *copy = *FMUState; /* an earlier state is overwritten in place */
    if (!copy) {
        copy = malloc(sizeof(State));
        if (!copy) return FAIL(inst, "fmi3GetFMUState: out of memory");
    }
    *copy = inst->s;
    *FMUState = copy;
    return fmi3OK;
}

fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState FMUState) {
    Instance *inst = as_instance(instance);
    if (!FMUState) return FAIL(inst, "fmi3SetFMUState: no state given");
    inst->s = *(const State *)FMUState;
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
    *size = sizeof(unsigned int) + sizeof(State);
    return fmi3OK;
}

fmi3Status fmi3SerializeFMUState(fmi3Instance instance, fmi3FMUState FMUState,
                                 fmi3Byte serializedState[], size_t size) {
    const unsigned int magic = STATE_MAGIC;
    if (size != sizeof magic + sizeof(State))
        return FAIL(as_instance(instance), "fmi3SerializeFMUState: buffer has %zu bytes, need %zu",
                    size, sizeof magic + sizeof(State));
    memcpy(serializedState, &magic, sizeof magic);
    memcpy(serializedState + sizeof magic, FMUState, sizeof(State));
    return fmi3OK;
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance instance, const fmi3Byte serializedState[],
                                   size_t size, fmi3FMUState *FMUState) {
    Instance *inst = as_instance(instance);
    unsigned int magic;
    if (size != sizeof magic + sizeof(State))
        return FAIL(inst, "fmi3DeserializeFMUState: %zu bytes is not a state of this FMU", size);
    memcpy(&magic, serializedState, sizeof magic);
    if (magic != STATE_MAGIC)
        return FAIL(inst, "fmi3DeserializeFMUState: bytes are not a state of this FMU");
    if (!*FMUState) {
        *FMUState = malloc(sizeof(State));
        if (!*FMUState) return FAIL(inst, "fmi3DeserializeFMUState: out of memory");
    }
    memcpy(*FMUState, serializedState + sizeof magic, sizeof(State));
    return fmi3OK;
}

/* ---- co-simulation -------------------------------------------------------------------------- */

fmi3Status fmi3EnterStepMode(fmi3Instance instance) {
    Instance *inst = as_instance(instance);
    if (inst->mode != MODE_STEP) return FAIL(inst, "fmi3EnterStepMode: not initialized");
    return fmi3OK;
}

fmi3Status fmi3GetOutputDerivatives(fmi3Instance instance,
                                    const fmi3ValueReference valueReferences[],
                                    size_t nValueReferences, const fmi3Int32 orders[],
                                    fmi3Float64 values[], size_t nValues) {
    Instance *inst = as_instance(instance);
    const PendulumParameters p = parameters(&inst->s);
    double dx[2];
    if (nValues != nValueReferences)
        return FAIL(inst, "fmi3GetOutputDerivatives: %zu values for %zu variables", nValues,
                    nValueReferences);
    pendulum_rhs(&p, &inst->s.v[VR_THETA], &inst->s.v[VR_U_THETA], dx);
    for (size_t i = 0; i < nValueReferences; i++) {
        const fmi3ValueReference vr = valueReferences[i];
        if (vr != VR_THETA && vr != VR_OMEGA)
            return FAIL(inst, "fmi3GetOutputDerivatives: value reference %u is not an output",
                        vr);
        if (orders[i] != 1)
            return FAIL(inst, "fmi3GetOutputDerivatives: only order 1 is provided, not %d",
                        orders[i]);
        values[i] = dx[vr - VR_THETA];
    }
    return fmi3OK;
}

fmi3Status fmi3DoStep(fmi3Instance instance, fmi3Float64 currentCommunicationPoint,
                      fmi3Float64 communicationStepSize,
                      fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                      fmi3Boolean *eventHandlingNeeded, fmi3Boolean *terminateSimulation,
                      fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime) {
    Instance *inst = as_instance(instance);
    State *s = &inst->s;
    /* the local steps span (a + h) - a, as OdeSubModel's RK4 over [t, t + h] does */
    const double a = currentCommunicationPoint, h = (a + communicationStepSize) - a;
    const PendulumParameters p = parameters(s);
    double x[2];
    (void)noSetFMUStatePriorToCurrentPoint;
    *eventHandlingNeeded = fmi3False;
    *terminateSimulation = fmi3False;
    *earlyReturn = fmi3False;
    *lastSuccessfulTime = s->v[VR_TIME];
    if (inst->mode != MODE_STEP) return FAIL(inst, "fmi3DoStep outside step mode");
    if (!(communicationStepSize > 0.0))
        return FAIL(inst, "fmi3DoStep: step size %g is not positive", communicationStepSize);
    if (fabs(a - s->v[VR_TIME]) > 1e-9 * fmax(1.0, fabs(s->v[VR_TIME])))
        return FAIL(inst, "fmi3DoStep: communication point %.17g differs from the FMU time %.17g",
                    a, s->v[VR_TIME]);
    x[0] = s->v[VR_THETA];
    x[1] = s->v[VR_OMEGA];
    if (pendulum_rk4(&p, a, h, s->v[VR_MAX_DT], &s->v[VR_U_THETA], x) != 0)
        return FAIL(inst, "fmi3DoStep: step %g needs more than %g local steps of max_dt = %g", h,
                    PENDULUM_MAX_SUBSTEPS, s->v[VR_MAX_DT]);
    if (!isfinite(x[0]) || !isfinite(x[1]))
        return FAIL(inst, "fmi3DoStep: state is not finite after the step from t = %g", a);
    s->v[VR_THETA] = x[0];
    s->v[VR_OMEGA] = x[1];
    s->v[VR_TIME] = a + communicationStepSize;
    *lastSuccessfulTime = s->v[VR_TIME];
    return fmi3OK;
}

/* ---- everything outside co-simulation without events ---------------------------------------- */

#define UNSUPPORTED(call) return FAIL(as_instance(instance), call ": not supported by this FMU")

#include "fmi3_unsupported.h"

fmi3Status fmi3UpdateDiscreteStates(fmi3Instance instance, fmi3Boolean *discreteStatesNeedUpdate,
                                    fmi3Boolean *terminateSimulation,
                                    fmi3Boolean *nominalsOfContinuousStatesChanged,
                                    fmi3Boolean *valuesOfContinuousStatesChanged,
                                    fmi3Boolean *nextEventTimeDefined,
                                    fmi3Float64 *nextEventTime) {
    (void)discreteStatesNeedUpdate, (void)terminateSimulation;
    (void)nominalsOfContinuousStatesChanged, (void)valuesOfContinuousStatesChanged;
    (void)nextEventTimeDefined, (void)nextEventTime;
    UNSUPPORTED("fmi3UpdateDiscreteStates");
}
fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance instance) {
    UNSUPPORTED("fmi3EnterContinuousTimeMode");
}
fmi3Status fmi3CompletedIntegratorStep(fmi3Instance instance,
                                       fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean *enterEventMode,
                                       fmi3Boolean *terminateSimulation) {
    (void)noSetFMUStatePriorToCurrentPoint, (void)enterEventMode, (void)terminateSimulation;
    UNSUPPORTED("fmi3CompletedIntegratorStep");
}
fmi3Status fmi3SetTime(fmi3Instance instance, fmi3Float64 time) {
    (void)time;
    UNSUPPORTED("fmi3SetTime");
}
fmi3Status fmi3SetContinuousStates(fmi3Instance instance, const fmi3Float64 continuousStates[],
                                   size_t nContinuousStates) {
    (void)continuousStates, (void)nContinuousStates;
    UNSUPPORTED("fmi3SetContinuousStates");
}
fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance instance, fmi3Float64 derivatives[],
                                             size_t nContinuousStates) {
    (void)derivatives, (void)nContinuousStates;
    UNSUPPORTED("fmi3GetContinuousStateDerivatives");
}
fmi3Status fmi3GetEventIndicators(fmi3Instance instance, fmi3Float64 eventIndicators[],
                                  size_t nEventIndicators) {
    (void)eventIndicators, (void)nEventIndicators;
    UNSUPPORTED("fmi3GetEventIndicators");
}
fmi3Status fmi3GetContinuousStates(fmi3Instance instance, fmi3Float64 continuousStates[],
                                   size_t nContinuousStates) {
    (void)continuousStates, (void)nContinuousStates;
    UNSUPPORTED("fmi3GetContinuousStates");
}
fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance instance, fmi3Float64 nominals[],
                                             size_t nContinuousStates) {
    (void)nominals, (void)nContinuousStates;
    UNSUPPORTED("fmi3GetNominalsOfContinuousStates");
}
fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance instance, size_t *nEventIndicators) {
    (void)nEventIndicators;
    UNSUPPORTED("fmi3GetNumberOfEventIndicators");
}
fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance instance, size_t *nContinuousStates) {
    (void)nContinuousStates;
    UNSUPPORTED("fmi3GetNumberOfContinuousStates");
}
