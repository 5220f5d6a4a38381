/* One bar of the split double pendulum as an FMI 2.0 co-simulation FMU.
 *
 * Compile with -DBAR=1 (upper bar) or -DBAR=2 (lower bar). The bar integrates its own angle theta
 * and angular velocity omega and receives the other bar's angle and angular velocity as inputs.
 * The numbers reproduce cosimstep.models.pendulum.bar(2, BAR, ...) driven by OdeSubModel with
 * RK4(max_dt): the same Runge-Kutta stages, the same number of local steps
 * n = max(1, ceil(h / max_dt - 1e-9)), the same input polynomial u + sum_k d_k dt^k / k! (k <= 3,
 * set with fmi2SetRealInputDerivatives) and the same re-expansion of that polynomial at the end of
 * a step. Expressions keep Python's evaluation order so results agree bit for bit; build without
 * floating-point contraction (-ffp-contract=off) for that.
 *
 * Setting an input with fmi2SetReal clears its derivatives, so a master that only sets values
 * gets inputs held constant over the step.
 */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "fmi2.h"
#include "pendulum_physics.h"

#if !defined(BAR) || (BAR != 1 && BAR != 2)
#error "compile with -DBAR=1 (upper bar) or -DBAR=2 (lower bar)"
#endif

#if BAR == 1
#define MODEL_GUID "{8c4e2d57-1b6f-4a0e-9d2c-3f5a7b9e1c01}"
#define THETA_START 0.4
#define OTHER_THETA_START (-0.3)
#else
#define MODEL_GUID "{8c4e2d57-1b6f-4a0e-9d2c-3f5a7b9e1c02}"
#define THETA_START (-0.3)
#define OTHER_THETA_START 0.4
#endif

#define INPUT_ORDER 3   /* highest input derivative followed during a step */
#define MAX_SUBSTEPS 100000000.0
#define STATE_MAGIC 0x43534231u /* "CSB1": tags serialized states */

/* Value references, as in modelDescription.xml. */
enum {
    VR_THETA, VR_OMEGA,        /* outputs: this bar's state */
    VR_U_THETA, VR_U_OMEGA,    /* inputs: the other bar's angle and angular velocity */
    VR_M1, VR_M2, VR_L1, VR_L2, VR_G, VR_MAX_DT,  /* parameters */
    N_VR
};

static const char *const VR_NAMES[N_VR] = {
    "theta", "omega",
#if BAR == 1
    "theta2", "omega2",
#else
    "theta1", "omega1",
#endif
    "m1", "m2", "l1", "l2", "g", "max_dt"
};

static const double START[N_VR] = {
    THETA_START, 0.0, OTHER_THETA_START, 0.0, 1.0, 1.0, 1.0, 1.0, 9.81, 1e-3
};

/* Everything a step depends on; fmi2GetFMUstate copies exactly this. */
typedef struct {
    double time;
    double v[N_VR];                  /* values by value reference */
    double du[INPUT_ORDER][2];       /* input derivatives, row k-1 holds the k-th */
} State;

typedef enum { MODE_INSTANTIATED, MODE_INITIALIZATION, MODE_STEP, MODE_TERMINATED } Mode;

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

/* This bar's dx/dt from the chain parameters stored in v (the physics is shared with the
 * FMI 3.0 and model-exchange bars). */
static void rhs(const double *v, const double x[2], const double u[2], double dx[2]) {
    const PendulumParameters p = {v[VR_M1], v[VR_M2], v[VR_L1], v[VR_L2], v[VR_G]};
    pendulum_rhs(&p, x, u, dx);
}

/* out = value + sum_{k=1..order} d[k-1] dt^k / k!, accumulated as OdeSubModel's _taylor. */
static void taylor(const double value[2], const double (*d)[2], int order, double dt,
                   double out[2]) {
    double term = 1.0;
    out[0] = value[0];
    out[1] = value[1];
    for (int k = 1; k <= order; k++) {
        term *= dt / k;
        out[0] = out[0] + term * d[k - 1][0];
        out[1] = out[1] + term * d[k - 1][1];
    }
}

typedef struct {
    const State *s;
    double t_start;
    int has_slope;
} Inputs;

static void derivative(const Inputs *in, double t, const double x[2], double dx[2]) {
    double u[2];
    if (in->has_slope) {
        taylor(&in->s->v[VR_U_THETA], (const double (*)[2])in->s->du, INPUT_ORDER,
               t - in->t_start, u);
        rhs(in->s->v, x, u, dx);
    } else {
        rhs(in->s->v, x, &in->s->v[VR_U_THETA], dx);
    }
}

static int is_input(fmi2ValueReference vr) { return vr == VR_U_THETA || vr == VR_U_OMEGA; }

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
    if (fmuType != fmi2CoSimulation) {
        log_status(inst, fmi2Error, "this FMU supports co-simulation only");
    } else if (!fmuGUID || strcmp(fmuGUID, MODEL_GUID) != 0) {
        log_status(inst, fmi2Error, "GUID %s does not match %s", fmuGUID ? fmuGUID : "(null)",
                   MODEL_GUID);
    } else {
        memcpy(inst->s.v, START, sizeof START);
        inst->mode = MODE_INSTANTIATED;
        log_status(inst, fmi2OK, "instantiated, GUID %s", MODEL_GUID);
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
    const double *v = inst->s.v;
    if (inst->mode != MODE_INITIALIZATION)
        return FAIL(inst, "fmi2ExitInitializationMode outside initialization mode");
    if (!(v[VR_MAX_DT] > 0.0))
        return FAIL(inst, "parameter max_dt must be positive, got %g", v[VR_MAX_DT]);
    if (!(v[VR_M1] > 0.0 && v[VR_M2] > 0.0 && v[VR_L1] > 0.0 && v[VR_L2] > 0.0))
        return FAIL(inst, "masses and lengths must be positive");
    inst->mode = MODE_STEP;
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component c) {
    as_instance(c)->mode = MODE_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component c) {
    Instance *inst = as_instance(c);
    memset(&inst->s, 0, sizeof inst->s);
    memcpy(inst->s.v, START, sizeof START);
    inst->mode = MODE_INSTANTIATED;
    return fmi2OK;
}

/* ---- getting and setting values --------------------------------------------------------- */

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       fmi2Real value[]) {
    Instance *inst = as_instance(c);
    for (size_t i = 0; i < nvr; i++) {
        if (vr[i] >= N_VR) return FAIL(inst, "fmi2GetReal: unknown value reference %u", vr[i]);
        value[i] = inst->s.v[vr[i]];
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       const fmi2Real value[]) {
    Instance *inst = as_instance(c);
    int before_step = inst->mode == MODE_INSTANTIATED || inst->mode == MODE_INITIALIZATION;
    for (size_t i = 0; i < nvr; i++) {
        if (vr[i] >= N_VR) return FAIL(inst, "fmi2SetReal: unknown value reference %u", vr[i]);
        if (!before_step && !(inst->mode == MODE_STEP && is_input(vr[i])))
            return FAIL(inst, "fmi2SetReal: %s can only be set before initialization ends",
                        VR_NAMES[vr[i]]);
    }
    for (size_t i = 0; i < nvr; i++) {
        inst->s.v[vr[i]] = value[i];
        if (is_input(vr[i]))
            for (int k = 0; k < INPUT_ORDER; k++) inst->s.du[k][vr[i] - VR_U_THETA] = 0.0;
    }
    return fmi2OK;
}

#define NO_VARIABLES(fname, type)                                                     \
    do {                                                                              \
        (void)vr;                                                                     \
        (void)value;                                                                  \
        if (nvr) return FAIL(as_instance(c), fname ": this FMU has no " type " variables"); \
        return fmi2OK;                                                                \
    } while (0)

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Integer value[]) {
    NO_VARIABLES("fmi2GetInteger", "Integer");
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Boolean value[]) {
    NO_VARIABLES("fmi2GetBoolean", "Boolean");
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         fmi2String value[]) {
    NO_VARIABLES("fmi2GetString", "String");
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Integer value[]) {
    NO_VARIABLES("fmi2SetInteger", "Integer");
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Boolean value[]) {
    NO_VARIABLES("fmi2SetBoolean", "Boolean");
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         const fmi2String value[]) {
    NO_VARIABLES("fmi2SetString", "String");
}

/* ---- FMU state ---------------------------------------------------------------------------- */

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    Instance *inst = as_instance(c);
    State *copy = *FMUstate;  /* an earlier state is overwritten in place */
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
    (void)c;
    (void)FMUstate;
    *size = sizeof(unsigned int) + sizeof(State);
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate,
                                 fmi2Byte serializedState[], size_t size) {
    const unsigned int magic = STATE_MAGIC;
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

/* ---- co-simulation ---------------------------------------------------------------------- */

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[],
                                       size_t nvr, const fmi2Integer order[],
                                       const fmi2Real value[]) {
    Instance *inst = as_instance(c);
    if (inst->mode != MODE_INITIALIZATION && inst->mode != MODE_STEP)
        return FAIL(inst, "fmi2SetRealInputDerivatives outside initialization or step mode");
    for (size_t i = 0; i < nvr; i++) {
        if (!is_input(vr[i]))
            return FAIL(inst, "fmi2SetRealInputDerivatives: value reference %u is not an input",
                        vr[i]);
        if (order[i] < 1 || order[i] > INPUT_ORDER)
            return FAIL(inst, "fmi2SetRealInputDerivatives: order %d not in 1..%d", order[i],
                        INPUT_ORDER);
    }
    for (size_t i = 0; i < nvr; i++) inst->s.du[order[i] - 1][vr[i] - VR_U_THETA] = value[i];
    return fmi2OK;
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[],
                                        size_t nvr, const fmi2Integer order[],
                                        fmi2Real value[]) {
    Instance *inst = as_instance(c);
    double dx[2];
    rhs(inst->s.v, &inst->s.v[VR_THETA], &inst->s.v[VR_U_THETA], dx);
    for (size_t i = 0; i < nvr; i++) {
        if (vr[i] != VR_THETA && vr[i] != VR_OMEGA)
            return FAIL(inst, "fmi2GetRealOutputDerivatives: value reference %u is not an output",
                        vr[i]);
        if (order[i] != 1)
            return FAIL(inst, "fmi2GetRealOutputDerivatives: only order 1 is provided, not %d",
                        order[i]);
        value[i] = dx[vr[i] - VR_THETA];
    }
    return fmi2OK;
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint,
                      fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    Instance *inst = as_instance(c);
    State *s = &inst->s;
    const double a = currentCommunicationPoint, b = a + communicationStepSize;
    const double h = b - a;
    Inputs in = {s, s->time, 0};
    double x[2], xs[2], k1[2], k2[2], k3[2], k4[2], steps, dt, span;
    double u_new[2], du_new[INPUT_ORDER][2];
    long n;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (inst->mode != MODE_STEP) return FAIL(inst, "fmi2DoStep outside step mode");
    if (!(communicationStepSize > 0.0))
        return FAIL(inst, "fmi2DoStep: step size %g is not positive", communicationStepSize);
    if (fabs(a - s->time) > 1e-9 * fmax(1.0, fabs(s->time)))
        return FAIL(inst, "fmi2DoStep: communication point %.17g differs from the FMU time %.17g",
                    a, s->time);
    steps = ceil(h / s->v[VR_MAX_DT] - 1e-9);
    if (!(steps <= MAX_SUBSTEPS))
        return FAIL(inst, "fmi2DoStep: step %g needs more than %g local steps of max_dt = %g",
                    h, MAX_SUBSTEPS, s->v[VR_MAX_DT]);
    n = steps < 1.0 ? 1 : (long)steps;
    dt = h / n;
    for (int k = 0; k < INPUT_ORDER; k++)
        in.has_slope |= s->du[k][0] != 0.0 || s->du[k][1] != 0.0;

    x[0] = s->v[VR_THETA];
    x[1] = s->v[VR_OMEGA];
    for (long i = 0; i < n; i++) {
        const double t = a + i * dt;
        derivative(&in, t, x, k1);
        for (int j = 0; j < 2; j++) xs[j] = x[j] + 0.5 * dt * k1[j];
        derivative(&in, t + 0.5 * dt, xs, k2);
        for (int j = 0; j < 2; j++) xs[j] = x[j] + 0.5 * dt * k2[j];
        derivative(&in, t + 0.5 * dt, xs, k3);
        for (int j = 0; j < 2; j++) xs[j] = x[j] + dt * k3[j];
        derivative(&in, t + dt, xs, k4);
        for (int j = 0; j < 2; j++)
            x[j] = x[j] + dt / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j]);
    }
    if (!isfinite(x[0]) || !isfinite(x[1]))
        return FAIL(inst, "fmi2DoStep: state is not finite after the step from t = %g", a);

    /* Re-expand the input polynomial around the new time, so outputs and output derivatives
       read now see the inputs valid now. */
    span = (a + communicationStepSize) - in.t_start;
    taylor(&s->v[VR_U_THETA], (const double (*)[2])s->du, INPUT_ORDER, span, u_new);
    for (int j = 0; j < INPUT_ORDER; j++)
        taylor(s->du[j], (const double (*)[2])&s->du[j + 1], INPUT_ORDER - 1 - j, span,
               du_new[j]);
    s->v[VR_THETA] = x[0];
    s->v[VR_OMEGA] = x[1];
    s->v[VR_U_THETA] = u_new[0];
    s->v[VR_U_OMEGA] = u_new[1];
    memcpy(s->du, du_new, sizeof du_new);
    s->time = a + communicationStepSize;
    return fmi2OK;
}

fmi2Status fmi2CancelStep(fmi2Component c) {
    return FAIL(as_instance(c), "fmi2CancelStep: steps are never asynchronous");
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    (void)c;
    (void)s;
    (void)value;
    return fmi2Discard;
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    if (s != fmi2LastSuccessfulTime) return fmi2Discard;
    *value = as_instance(c)->s.time;
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
    *value = as_instance(c)->mode == MODE_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
    (void)c;
    (void)s;
    (void)value;
    return fmi2Discard;
}
