/* An FMI 2.0 co-simulation FMU around a small ODE, integrated inside by classic RK4.
 *
 * A model file defines what makes it itself and then includes this header, which supplies
 * every fmi2* function:
 *
 *   MODEL_GUID          the GUID of its modelDescription.xml
 *   N_X, N_U, N_P       states (all of them outputs), real inputs, parameters; value references
 *                       are laid out as [states | inputs | parameters], and the last parameter
 *                       is max_dt, the largest internal RK4 step
 *   static const char *const VR_NAMES[N_X + N_U + N_P];
 *   static const double START[N_X + N_U + N_P];
 *   static void model_rhs(const double *par, double t, const double *x, const double *u,
 *                         double *dx);          (par points at the first parameter)
 *   static const char *model_check(const double *par);   (NULL, or why the parameters are bad)
 *
 * The master may set input derivatives (canInterpolateInputs): over a step the inputs follow
 * u + sum_k d_k (t - t0)^k / k!, k <= ODE_INPUT_ORDER, and at the end of a step that polynomial
 * is re-expanded about the new time. Setting an input with fmi2SetReal clears its derivatives.
 * The state (time, values, input derivatives) can be got, set and serialized, so a master can
 * roll steps back. One step of h takes n = max(1, ceil(h / max_dt)) equal RK4 steps, as
 * cosimstep's OdeSubModel does with the RK4 internal solver.
 */
#ifndef COSIMSTEP_FMI2_CS_ODE_H
#define COSIMSTEP_FMI2_CS_ODE_H

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "fmi2.h"

#define ODE_INPUT_ORDER 3
#define ODE_N_VR (N_X + N_U + N_P)
#define ODE_PAR (N_X + N_U) /* first parameter */
#define ODE_MAX_DT (ODE_N_VR - 1)
#define ODE_MAX_SUBSTEPS 1e8
#define ODE_STATE_MAGIC 0x4f444531u /* "ODE1" */

typedef struct {
    double time;
    double v[ODE_N_VR];
    double du[ODE_INPUT_ORDER][N_U]; /* row k-1: the k-th input derivatives */
} OdeState;

typedef enum { ODE_INSTANTIATED, ODE_INITIALIZATION, ODE_STEP, ODE_TERMINATED } OdeMode;

typedef struct {
    OdeState s;
    OdeMode mode;
    fmi2CallbackFunctions cb;
    char *name;
    fmi2Boolean logging;
} OdeInstance;

static OdeInstance *ode(fmi2Component c) { return (OdeInstance *)c; }

static void ode_log(const OdeInstance *inst, fmi2Status status, const char *fmt, ...) {
    char text[512];
    va_list args;
    if (!inst->cb.logger || (status == fmi2OK && !inst->logging)) return;
    va_start(args, fmt);
    vsnprintf(text, sizeof text, fmt, args);
    va_end(args);
    inst->cb.logger(inst->cb.componentEnvironment, inst->name, status,
                    status == fmi2OK ? "logAll" : "logStatusError", "%s", text);
}

#define ODE_FAIL(inst, ...) (ode_log((inst), fmi2Error, __VA_ARGS__), fmi2Error)

static int ode_is_input(fmi2ValueReference vr) { return vr >= N_X && vr < ODE_PAR; }

/* The inputs at offset dt from the start of the polynomial (value + derivatives). */
static void ode_inputs(const double *value, const double (*d)[N_U], int order, double dt,
                       double *out) {
    double term = 1.0;
    for (int j = 0; j < N_U; j++) out[j] = value[j];
    for (int k = 1; k <= order; k++) {
        term *= dt / k;
        for (int j = 0; j < N_U; j++) out[j] += term * d[k - 1][j];
    }
}

static void ode_derivative(const OdeState *s, double t0, double t, const double *x, double *dx) {
    double u[N_U > 0 ? N_U : 1];
    ode_inputs(&s->v[N_X], (const double (*)[N_U])s->du, ODE_INPUT_ORDER, t - t0, u);
    model_rhs(&s->v[ODE_PAR], t, x, u, dx);
}

/* ---- life cycle --------------------------------------------------------------------------- */

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    (void)nCategories;
    (void)categories;
    ode(c)->logging = loggingOn;
    return fmi2OK;
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation,
                              const fmi2CallbackFunctions *functions, fmi2Boolean visible,
                              fmi2Boolean loggingOn) {
    OdeInstance *inst;
    size_t n = instanceName ? strlen(instanceName) : 0;
    (void)fmuResourceLocation;
    (void)visible;
    if (!functions || !functions->allocateMemory || !functions->freeMemory) return NULL;
    inst = functions->allocateMemory(1, sizeof(OdeInstance));
    if (!inst) return NULL;
    inst->cb = *functions;
    inst->logging = loggingOn;
    inst->name = functions->allocateMemory(n + 1, 1);
    if (inst->name) {
        if (n) memcpy(inst->name, instanceName, n);
        if (fmuType != fmi2CoSimulation) {
            ode_log(inst, fmi2Error, "this FMU supports co-simulation only");
        } else if (!fmuGUID || strcmp(fmuGUID, MODEL_GUID) != 0) {
            ode_log(inst, fmi2Error, "GUID %s does not match %s", fmuGUID ? fmuGUID : "(null)",
                    MODEL_GUID);
        } else {
            memcpy(inst->s.v, START, sizeof START);
            inst->mode = ODE_INSTANTIATED;
            ode_log(inst, fmi2OK, "instantiated, GUID %s", MODEL_GUID);
            return inst;
        }
        functions->freeMemory(inst->name);
    }
    functions->freeMemory(inst);
    return NULL;
}

void fmi2FreeInstance(fmi2Component c) {
    OdeInstance *inst = ode(c);
    if (!inst) return;
    inst->cb.freeMemory(inst->name);
    inst->cb.freeMemory(inst);
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined,
                               fmi2Real stopTime) {
    OdeInstance *inst = ode(c);
    (void)toleranceDefined;
    (void)tolerance;
    (void)stopTimeDefined;
    (void)stopTime;
    if (inst->mode != ODE_INSTANTIATED)
        return ODE_FAIL(inst, "fmi2SetupExperiment is only allowed after fmi2Instantiate");
    inst->s.time = startTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    OdeInstance *inst = ode(c);
    if (inst->mode != ODE_INSTANTIATED)
        return ODE_FAIL(inst, "fmi2EnterInitializationMode is only allowed after fmi2Instantiate");
    inst->mode = ODE_INITIALIZATION;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    OdeInstance *inst = ode(c);
    const char *why;
    if (inst->mode != ODE_INITIALIZATION)
        return ODE_FAIL(inst, "fmi2ExitInitializationMode outside initialization mode");
    if (!(inst->s.v[ODE_MAX_DT] > 0.0))
        return ODE_FAIL(inst, "parameter max_dt must be positive, got %g", inst->s.v[ODE_MAX_DT]);
    why = model_check(&inst->s.v[ODE_PAR]);
    if (why) return ODE_FAIL(inst, "%s", why);
    inst->mode = ODE_STEP;
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component c) {
    ode(c)->mode = ODE_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component c) {
    OdeInstance *inst = ode(c);
    memset(&inst->s, 0, sizeof inst->s);
    memcpy(inst->s.v, START, sizeof START);
    inst->mode = ODE_INSTANTIATED;
    return fmi2OK;
}

/* ---- values -------------------------------------------------------------------------------- */

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       fmi2Real value[]) {
    OdeInstance *inst = ode(c);
    for (size_t i = 0; i < nvr; i++) {
        if (vr[i] >= ODE_N_VR) return ODE_FAIL(inst, "fmi2GetReal: unknown value reference %u", vr[i]);
        value[i] = inst->s.v[vr[i]];
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       const fmi2Real value[]) {
    OdeInstance *inst = ode(c);
    const int early = inst->mode == ODE_INSTANTIATED || inst->mode == ODE_INITIALIZATION;
    for (size_t i = 0; i < nvr; i++) {
        if (vr[i] >= ODE_N_VR) return ODE_FAIL(inst, "fmi2SetReal: unknown value reference %u", vr[i]);
        if (!early && !(inst->mode == ODE_STEP && ode_is_input(vr[i])))
            return ODE_FAIL(inst, "fmi2SetReal: %s can only be set before initialization ends",
                            VR_NAMES[vr[i]]);
    }
    for (size_t i = 0; i < nvr; i++) {
        inst->s.v[vr[i]] = value[i];
        if (ode_is_input(vr[i]))
            for (int k = 0; k < ODE_INPUT_ORDER; k++) inst->s.du[k][vr[i] - N_X] = 0.0;
    }
    return fmi2OK;
}

#define REALS_ONLY_FAIL(c, msg) ODE_FAIL(ode(c), msg)
#include "fmi2_reals_only.h"

/* ---- the FMU state: what a rollback restores ----------------------------------------------- */

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    OdeInstance *inst = ode(c);
    OdeState *copy = *FMUstate; /* a state passed in is overwritten in place */
    if (!copy) {
        copy = inst->cb.allocateMemory(1, sizeof(OdeState));
        if (!copy) return ODE_FAIL(inst, "fmi2GetFMUstate: out of memory");
    }
    *copy = inst->s;
    *FMUstate = copy;
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    if (!FMUstate) return ODE_FAIL(ode(c), "fmi2SetFMUstate: no state given");
    ode(c)->s = *(const OdeState *)FMUstate;
    return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    if (FMUstate && *FMUstate) {
        ode(c)->cb.freeMemory(*FMUstate);
        *FMUstate = NULL;
    }
    return fmi2OK;
}

#define ODE_SERIALIZED (sizeof(unsigned int) + sizeof(OdeState))

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size) {
    (void)c;
    (void)FMUstate;
    *size = ODE_SERIALIZED;
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate,
                                 fmi2Byte serializedState[], size_t size) {
    const unsigned int magic = ODE_STATE_MAGIC;
    if (size != ODE_SERIALIZED)
        return ODE_FAIL(ode(c), "fmi2SerializeFMUstate: buffer has %zu bytes, need %zu", size,
                        (size_t)ODE_SERIALIZED);
    memcpy(serializedState, &magic, sizeof magic);
    memcpy(serializedState + sizeof magic, FMUstate, sizeof(OdeState));
    return fmi2OK;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[],
                                   size_t size, fmi2FMUstate *FMUstate) {
    OdeInstance *inst = ode(c);
    unsigned int magic = 0;
    if (size == ODE_SERIALIZED) memcpy(&magic, serializedState, sizeof magic);
    if (magic != ODE_STATE_MAGIC)
        return ODE_FAIL(inst, "fmi2DeSerializeFMUstate: the bytes are not a state of this FMU");
    if (!*FMUstate) {
        *FMUstate = inst->cb.allocateMemory(1, sizeof(OdeState));
        if (!*FMUstate) return ODE_FAIL(inst, "fmi2DeSerializeFMUstate: out of memory");
    }
    memcpy(*FMUstate, serializedState + sizeof magic, sizeof(OdeState));
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
    return ODE_FAIL(ode(c), "fmi2GetDirectionalDerivative is not provided");
}

/* ---- stepping ------------------------------------------------------------------------------ */

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[],
                                       size_t nvr, const fmi2Integer order[],
                                       const fmi2Real value[]) {
    OdeInstance *inst = ode(c);
    if (inst->mode != ODE_INITIALIZATION && inst->mode != ODE_STEP)
        return ODE_FAIL(inst, "fmi2SetRealInputDerivatives outside initialization or step mode");
    for (size_t i = 0; i < nvr; i++) {
        if (!ode_is_input(vr[i]))
            return ODE_FAIL(inst, "fmi2SetRealInputDerivatives: %u is not an input", vr[i]);
        if (order[i] < 1 || order[i] > ODE_INPUT_ORDER)
            return ODE_FAIL(inst, "fmi2SetRealInputDerivatives: order %d not in 1..%d", order[i],
                            ODE_INPUT_ORDER);
    }
    for (size_t i = 0; i < nvr; i++) inst->s.du[order[i] - 1][vr[i] - N_X] = value[i];
    return fmi2OK;
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[],
                                        size_t nvr, const fmi2Integer order[],
                                        fmi2Real value[]) {
    OdeInstance *inst = ode(c);
    double dx[N_X];
    model_rhs(&inst->s.v[ODE_PAR], inst->s.time, inst->s.v, &inst->s.v[N_X], dx);
    for (size_t i = 0; i < nvr; i++) {
        if (vr[i] >= N_X)
            return ODE_FAIL(inst, "fmi2GetRealOutputDerivatives: %u is not an output", vr[i]);
        if (order[i] != 1)
            return ODE_FAIL(inst, "fmi2GetRealOutputDerivatives: only order 1, not %d", order[i]);
        value[i] = dx[vr[i]];
    }
    return fmi2OK;
}

/* Move the input polynomial's origin by span: values and derivatives valid at the new time. */
static void ode_shift_inputs(OdeState *s, double span) {
    double u[N_U > 0 ? N_U : 1], d[ODE_INPUT_ORDER][N_U > 0 ? N_U : 1];
    ode_inputs(&s->v[N_X], (const double (*)[N_U])s->du, ODE_INPUT_ORDER, span, u);
    for (int k = 0; k < ODE_INPUT_ORDER; k++)
        ode_inputs(s->du[k], (const double (*)[N_U])&s->du[k + 1], ODE_INPUT_ORDER - 1 - k,
                   span, d[k]);
    memcpy(&s->v[N_X], u, N_U * sizeof(double));
    memcpy(s->du, d, sizeof s->du);
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint,
                      fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    OdeInstance *inst = ode(c);
    OdeState *s = &inst->s;
    /* h as the step's end minus its start (as OdeSubModel takes it); t0: where the input
       polynomial was set (the FMU's time, within 1e-9 of a) */
    const double a = currentCommunicationPoint, b = a + communicationStepSize, h = b - a;
    const double t0 = s->time;
    double x[N_X], xs[N_X], k1[N_X], k2[N_X], k3[N_X], k4[N_X], steps, dt;
    long n;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (inst->mode != ODE_STEP) return ODE_FAIL(inst, "fmi2DoStep outside step mode");
    if (!(communicationStepSize > 0.0))
        return ODE_FAIL(inst, "fmi2DoStep: step size %g is not positive", communicationStepSize);
    if (fabs(a - s->time) > 1e-9 * fmax(1.0, fabs(s->time)))
        return ODE_FAIL(inst, "fmi2DoStep: communication point %.17g differs from the FMU time "
                        "%.17g", a, s->time);
    steps = ceil(h / s->v[ODE_MAX_DT] - 1e-9);
    if (!(steps <= ODE_MAX_SUBSTEPS))
        return ODE_FAIL(inst, "fmi2DoStep: a step of %g needs more than %g steps of max_dt = %g",
                        h, ODE_MAX_SUBSTEPS, s->v[ODE_MAX_DT]);
    n = steps < 1.0 ? 1 : (long)steps;
    dt = h / n;
    memcpy(x, s->v, sizeof x);
    for (long i = 0; i < n; i++) {
        const double t = a + i * dt;
        ode_derivative(s, t0, t, x, k1);
        for (int j = 0; j < N_X; j++) xs[j] = x[j] + 0.5 * dt * k1[j];
        ode_derivative(s, t0, t + 0.5 * dt, xs, k2);
        for (int j = 0; j < N_X; j++) xs[j] = x[j] + 0.5 * dt * k2[j];
        ode_derivative(s, t0, t + 0.5 * dt, xs, k3);
        for (int j = 0; j < N_X; j++) xs[j] = x[j] + dt * k3[j];
        ode_derivative(s, t0, t + dt, xs, k4);
        for (int j = 0; j < N_X; j++)
            x[j] = x[j] + dt / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j]);
    }
    for (int j = 0; j < N_X; j++)
        if (!isfinite(x[j]))
            return ODE_FAIL(inst, "fmi2DoStep: %s is not finite after the step from t = %g",
                            VR_NAMES[j], a);
    memcpy(s->v, x, sizeof x);
    ode_shift_inputs(s, b - t0); /* as OdeSubModel: the end time minus the start */
    s->time = b;
    return fmi2OK;
}

fmi2Status fmi2CancelStep(fmi2Component c) {
    return ODE_FAIL(ode(c), "fmi2CancelStep: steps are never asynchronous");
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    (void)c;
    (void)s;
    (void)value;
    return fmi2Discard;
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    if (s != fmi2LastSuccessfulTime) return fmi2Discard;
    *value = ode(c)->s.time;
    return fmi2OK;
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value) {
    (void)c;
    (void)s;
    (void)value;
    return fmi2Discard;
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value) {
    if (s != fmi2Terminated) return fmi2Discard;
    *value = ode(c)->mode == ODE_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
    (void)c;
    (void)s;
    (void)value;
    return fmi2Discard;
}

#endif /* COSIMSTEP_FMI2_CS_ODE_H */
