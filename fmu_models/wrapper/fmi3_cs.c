/*
 * fmi3_cs.c -- generic FMI 3.0 co-simulation wrapper for a fixed-step discrete-time
 * system described by system.h (x(k+1) = f(x, u, p), y = g(x, u, p), x0 = x0(p)).
 *
 * Same semantics as fmi2_cs.c (see there); FMI 3 specifics:
 *   - value reference 0 is the independent variable `time` (read-only);
 *   - no Event Mode, no clocks, no intermediate update, no early return: the
 *     co-simulation interface only (Model Exchange / Scheduled Execution
 *     instantiation returns NULL with a log message);
 *   - memory comes from malloc/free (FMI 3 has no memory callbacks);
 *   - fmi3DoStep returns lastSuccessfulTime = the FMU time after the call.
 *
 * Value references: 0 time, outputs 1..NY, inputs NY+1..NY+NU,
 * parameters NY+NU+1..NY+NU+NP. Units are SI (see modelDescription.xml).
 */
#include <math.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi3Functions.h"
#include "system.h"

#define DIM(n) ((n) > 0 ? (n) : 1)
#define VR_TIME 0u
#define VR_OUT0 1u
#define VR_IN0 (VR_OUT0 + (unsigned)SYS_NY)
#define VR_PAR0 (VR_IN0 + (unsigned)SYS_NU)
#define VR_END (VR_PAR0 + (unsigned)SYS_NP)

#define TIME_TOL 1e-9
#define STEP_TOL 1e-9

enum {
    MODE_INSTANTIATED = 1,
    MODE_INIT = 2,
    MODE_STEP = 4,
    MODE_TERMINATED = 8,
    MODE_ERROR = 16
};
#define MODE_ANY (MODE_INSTANTIATED | MODE_INIT | MODE_STEP | MODE_TERMINATED | MODE_ERROR)

typedef struct {
    double x[DIM(SYS_NX)];
    double u[DIM(SYS_NU)];
    double p[DIM(SYS_NP)];
    double time;
    int32_t mode;
    int32_t x_ready;
} CoreState;

#define STATE_MAGIC "LPVPCS3\0"
#define STATE_VERSION 1u

typedef struct {
    char magic[8];
    uint32_t version, nx, nu, np, ny, pad;
    uint64_t token_hash;
    CoreState s;
} FmuState;

typedef struct {
    CoreState s;
    double y[DIM(SYS_NY)];
    int y_valid;
    int logging_on;
    uint64_t token_hash;
    fmi3LogMessageCallback logger;
    fmi3InstanceEnvironment env;
    char *name;
} Instance;

static const double param_defaults[DIM(SYS_NP)] = SYS_PARAM_DEFAULTS;
static const double input_defaults[DIM(SYS_NU)] = SYS_INPUT_DEFAULTS;
static const char *const output_names[DIM(SYS_NY)] = SYS_OUTPUT_NAMES;
static const char *const input_names[DIM(SYS_NU)] = SYS_INPUT_NAMES;
static const char *const param_names[DIM(SYS_NP)] = SYS_PARAM_NAMES;

/* ------------------------------------------------------------------ helpers */

static uint64_t hash_string(const char *s)
{
    uint64_t h = 1469598103934665603ULL;
    while (s && *s) {
        h ^= (unsigned char)*s++;
        h *= 1099511628211ULL;
    }
    return h;
}

static void vlog(Instance *c, fmi3Status status, const char *category, const char *fmt, va_list ap)
{
    char buf[1024];
    if (!c || !c->logger) return;
    if (status == fmi3OK && !c->logging_on) return;
    vsnprintf(buf, sizeof buf, fmt, ap);
    c->logger(c->env, status, category, buf);
}

static void log_error(Instance *c, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vlog(c, fmi3Error, "logStatusError", fmt, ap);
    va_end(ap);
}

static void log_warning(Instance *c, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vlog(c, fmi3Warning, "logStatusWarning", fmt, ap);
    va_end(ap);
}

static void log_info(Instance *c, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vlog(c, fmi3OK, "logAll", fmt, ap);
    va_end(ap);
}

static const char *mode_name(int mode)
{
    switch (mode) {
    case MODE_INSTANTIATED: return "instantiated";
    case MODE_INIT: return "initialization mode";
    case MODE_STEP: return "step mode";
    case MODE_TERMINATED: return "terminated";
    case MODE_ERROR: return "error (after a failed step: only get values, get/set FMU state, reset or free)";
    default: return "unknown";
    }
}

static void allowed_modes(int mask, char *buf, size_t n)
{
    static const int modes[] = {MODE_INSTANTIATED, MODE_INIT, MODE_STEP, MODE_TERMINATED, MODE_ERROR};
    static const char *names[] = {"instantiated", "initialization mode", "step mode", "terminated", "error"};
    size_t k, used = 0;
    buf[0] = '\0';
    for (k = 0; k < sizeof modes / sizeof modes[0]; k++) {
        if (mask & modes[k]) {
            int w = snprintf(buf + used, n - used, "%s%s", used ? ", " : "", names[k]);
            if (w < 0 || (size_t)w >= n - used) break;
            used += (size_t)w;
        }
    }
}

static int check_mode(Instance *c, int mask, const char *fn)
{
    char allowed[160];
    if (!c) return 0;
    if (c->s.mode & mask) return 1;
    allowed_modes(mask, allowed, sizeof allowed);
    log_error(c, "%s: illegal call sequence: the instance is in %s; allowed in: %s.", fn,
              mode_name(c->s.mode), allowed);
    return 0;
}

static void describe_vr(fmi3ValueReference vr, char *buf, size_t n)
{
    if (vr == VR_TIME)
        snprintf(buf, n, "independent variable 'time' (vr 0)");
    else if (vr >= VR_OUT0 && vr < VR_IN0)
        snprintf(buf, n, "output '%s' (vr %u)", output_names[vr - VR_OUT0], (unsigned)vr);
    else if (vr >= VR_IN0 && vr < VR_PAR0)
        snprintf(buf, n, "input '%s' (vr %u)", input_names[vr - VR_IN0], (unsigned)vr);
    else if (vr >= VR_PAR0 && vr < VR_END)
        snprintf(buf, n, "parameter '%s' (vr %u)", param_names[vr - VR_PAR0], (unsigned)vr);
    else
        snprintf(buf, n, "vr %u", (unsigned)vr);
}

static int all_finite(const double *v, int n, int *bad)
{
    int i;
    for (i = 0; i < n; i++) {
        if (!isfinite(v[i])) {
            *bad = i;
            return 0;
        }
    }
    return 1;
}

static void set_start_values(Instance *c, double start_time)
{
    memset(&c->s, 0, sizeof c->s);
    memcpy(c->s.p, param_defaults, sizeof c->s.p);
    memcpy(c->s.u, input_defaults, sizeof c->s.u);
    c->s.time = start_time;
    c->s.mode = MODE_INSTANTIATED;
    c->s.x_ready = 0;
    c->y_valid = 0;
}

static int ensure_state(Instance *c, const char *fn)
{
    int rc, bad;
    if (c->s.x_ready) return 1;
    rc = sys_initial_state(c->s.p, c->s.x);
    if (rc != 0) {
        log_error(c, "%s: sys_initial_state failed (code %d) for the current parameter values.", fn, rc);
        return 0;
    }
    if (!all_finite(c->s.x, SYS_NX, &bad)) {
        log_error(c, "%s: the initial state x[%d] = %g is not finite for the current parameter values.", fn, bad,
                  c->s.x[bad]);
        return 0;
    }
    c->s.x_ready = 1;
    return 1;
}

static int ensure_outputs(Instance *c, const char *fn)
{
    int rc, bad;
    if (c->y_valid) return 1;
    if (!ensure_state(c, fn)) return 0;
    rc = sys_output(c->s.x, c->s.u, c->s.p, c->y);
    if (rc != 0) {
        log_error(c, "%s: sys_output failed (code %d) at t = %.17g.", fn, rc, c->s.time);
        return 0;
    }
    if (!all_finite(c->y, SYS_NY, &bad)) {
        log_error(c, "%s: output '%s' (vr %u) is %g (not finite) at t = %.17g.", fn, output_names[bad],
                  (unsigned)(VR_OUT0 + bad), c->y[bad], c->s.time);
        return 0;
    }
    c->y_valid = 1;
    return 1;
}

#define INSTANCE(inst) Instance *c = (Instance *)(inst)
#define REQUIRE(inst, mask, fn)                                                                          \
    INSTANCE(inst);                                                                                      \
    if (!c) return fmi3Error;                                                                            \
    if (!check_mode(c, (mask), (fn))) return fmi3Error

#define NOT_SUPPORTED(inst, fn, why)                                                                     \
    do {                                                                                                 \
        INSTANCE(inst);                                                                                  \
        if (!c) return fmi3Error;                                                                        \
        log_error(c, "%s: not supported by this co-simulation FMU (%s).", (fn), (why));                 \
        return fmi3Error;                                                                                \
    } while (0)

/* ------------------------------------------------------ inquiry and logging */

FMI3_Export const char *fmi3GetVersion(void) { return fmi3Version; }

FMI3_Export fmi3Status fmi3SetDebugLogging(fmi3Instance instance, fmi3Boolean loggingOn, size_t nCategories,
                                           const fmi3String categories[])
{
    static const char *known[] = {"logStatusError", "logStatusWarning", "logAll"};
    size_t i, k;
    fmi3Status status = fmi3OK;
    REQUIRE(instance, MODE_ANY, "fmi3SetDebugLogging");
    c->logging_on = loggingOn ? 1 : 0;
    if (nCategories > 0 && !categories) {
        log_error(c, "fmi3SetDebugLogging: categories is NULL but nCategories = %zu.", nCategories);
        return fmi3Error;
    }
    for (i = 0; i < nCategories; i++) {
        int found = 0;
        for (k = 0; k < sizeof known / sizeof known[0]; k++)
            if (categories[i] && strcmp(categories[i], known[k]) == 0) found = 1;
        if (!found) {
            log_warning(c, "fmi3SetDebugLogging: unknown log category '%s' (known: logStatusError, "
                           "logStatusWarning, logAll).",
                        categories[i] ? categories[i] : "(null)");
            status = fmi3Warning;
        }
    }
    return status;
}

/* ------------------------------------------------- creation and destruction */

FMI3_Export fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                                      fmi3String resourcePath, fmi3Boolean visible,
                                                      fmi3Boolean loggingOn, fmi3InstanceEnvironment instanceEnvironment,
                                                      fmi3LogMessageCallback logMessage)
{
    (void)instanceName;
    (void)instantiationToken;
    (void)resourcePath;
    (void)visible;
    (void)loggingOn;
    if (logMessage)
        logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                   "fmi3InstantiateModelExchange: " SYS_MODEL_IDENTIFIER " supports co-simulation only.");
    return NULL;
}

FMI3_Export fmi3Instance fmi3InstantiateScheduledExecution(
    fmi3String instanceName, fmi3String instantiationToken, fmi3String resourcePath, fmi3Boolean visible,
    fmi3Boolean loggingOn, fmi3InstanceEnvironment instanceEnvironment, fmi3LogMessageCallback logMessage,
    fmi3ClockUpdateCallback clockUpdate, fmi3LockPreemptionCallback lockPreemption,
    fmi3UnlockPreemptionCallback unlockPreemption)
{
    (void)instanceName;
    (void)instantiationToken;
    (void)resourcePath;
    (void)visible;
    (void)loggingOn;
    (void)clockUpdate;
    (void)lockPreemption;
    (void)unlockPreemption;
    if (logMessage)
        logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                   "fmi3InstantiateScheduledExecution: " SYS_MODEL_IDENTIFIER " supports co-simulation only.");
    return NULL;
}

FMI3_Export fmi3Instance fmi3InstantiateCoSimulation(
    fmi3String instanceName, fmi3String instantiationToken, fmi3String resourcePath, fmi3Boolean visible,
    fmi3Boolean loggingOn, fmi3Boolean eventModeUsed, fmi3Boolean earlyReturnAllowed,
    const fmi3ValueReference requiredIntermediateVariables[], size_t nRequiredIntermediateVariables,
    fmi3InstanceEnvironment instanceEnvironment, fmi3LogMessageCallback logMessage,
    fmi3IntermediateUpdateCallback intermediateUpdate)
{
    Instance tmp, *c;
    size_t len;
    (void)resourcePath;
    (void)visible;
    (void)eventModeUsed; /* hasEventMode=false: the FMU never needs Event Mode */
    (void)earlyReturnAllowed;
    (void)requiredIntermediateVariables;
    (void)intermediateUpdate;
    memset(&tmp, 0, sizeof tmp);
    tmp.logger = logMessage;
    tmp.env = instanceEnvironment;
    if (!instanceName || !instanceName[0]) {
        log_error(&tmp, "fmi3InstantiateCoSimulation: missing instance name.");
        return NULL;
    }
    if (!instantiationToken || strcmp(instantiationToken, SYS_GUID) != 0) {
        log_error(&tmp, "fmi3InstantiateCoSimulation: instantiationToken '%s' does not match this binary's token "
                        "'%s' (modelDescription.xml and binary come from different builds).",
                  instantiationToken ? instantiationToken : "(null)", SYS_GUID);
        return NULL;
    }
    if (nRequiredIntermediateVariables > 0) {
        log_error(&tmp, "fmi3InstantiateCoSimulation: intermediate variable access is not supported "
                        "(providesIntermediateUpdate=false).");
        return NULL;
    }
    c = (Instance *)calloc(1, sizeof(Instance));
    if (!c) {
        log_error(&tmp, "fmi3InstantiateCoSimulation: out of memory.");
        return NULL;
    }
    len = strlen(instanceName);
    c->name = (char *)malloc(len + 1);
    if (!c->name) {
        free(c);
        log_error(&tmp, "fmi3InstantiateCoSimulation: out of memory.");
        return NULL;
    }
    memcpy(c->name, instanceName, len + 1);
    c->logger = logMessage;
    c->env = instanceEnvironment;
    c->logging_on = loggingOn ? 1 : 0;
    c->token_hash = hash_string(SYS_GUID);
    set_start_values(c, 0.0);
    log_info(c, "fmi3InstantiateCoSimulation: %s, %d states, %d inputs, %d outputs, %d parameters, step %g s.",
             SYS_MODEL_IDENTIFIER, SYS_NX, SYS_NU, SYS_NY, SYS_NP, (double)SYS_STEP);
    return (fmi3Instance)c;
}

FMI3_Export void fmi3FreeInstance(fmi3Instance instance)
{
    INSTANCE(instance);
    if (!c) return;
    free(c->name);
    c->name = NULL;
    free(c);
}

/* ------------------------------------------- initialization, termination */

FMI3_Export fmi3Status fmi3EnterInitializationMode(fmi3Instance instance, fmi3Boolean toleranceDefined,
                                                   fmi3Float64 tolerance, fmi3Float64 startTime,
                                                   fmi3Boolean stopTimeDefined, fmi3Float64 stopTime)
{
    (void)toleranceDefined;
    (void)tolerance;
    REQUIRE(instance, MODE_INSTANTIATED, "fmi3EnterInitializationMode");
    if (!isfinite(startTime)) {
        log_error(c, "fmi3EnterInitializationMode: startTime = %g is not finite.", startTime);
        return fmi3Error;
    }
    if (stopTimeDefined && !(stopTime >= startTime)) {
        log_error(c, "fmi3EnterInitializationMode: stopTime = %g is before startTime = %g.", stopTime, startTime);
        return fmi3Error;
    }
    c->s.time = startTime;
    c->s.mode = MODE_INIT;
    return fmi3OK;
}

FMI3_Export fmi3Status fmi3ExitInitializationMode(fmi3Instance instance)
{
    REQUIRE(instance, MODE_INIT, "fmi3ExitInitializationMode");
    if (!ensure_state(c, "fmi3ExitInitializationMode")) return fmi3Error;
    c->y_valid = 0;
    if (!ensure_outputs(c, "fmi3ExitInitializationMode")) return fmi3Error;
    c->s.mode = MODE_STEP;
    log_info(c, "fmi3ExitInitializationMode: step mode at t = %.17g.", c->s.time);
    return fmi3OK;
}

FMI3_Export fmi3Status fmi3EnterEventMode(fmi3Instance instance)
{
    NOT_SUPPORTED(instance, "fmi3EnterEventMode", "hasEventMode=false");
}

FMI3_Export fmi3Status fmi3Terminate(fmi3Instance instance)
{
    REQUIRE(instance, MODE_STEP | MODE_ERROR, "fmi3Terminate");
    c->s.mode = MODE_TERMINATED;
    return fmi3OK;
}

FMI3_Export fmi3Status fmi3Reset(fmi3Instance instance)
{
    REQUIRE(instance, MODE_ANY, "fmi3Reset");
    set_start_values(c, 0.0);
    log_info(c, "fmi3Reset: back to the instantiated state with default values.");
    return fmi3OK;
}

/* ------------------------------------------------------- getting / setting */

#define GET_MODES (MODE_INIT | MODE_STEP | MODE_TERMINATED | MODE_ERROR)
#define SET_MODES (MODE_INSTANTIATED | MODE_INIT | MODE_STEP)

FMI3_Export fmi3Status fmi3GetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                      size_t nValueReferences, fmi3Float64 values[], size_t nValues)
{
    size_t i;
    REQUIRE(instance, GET_MODES, "fmi3GetFloat64");
    if (nValueReferences == 0) return fmi3OK;
    if (!valueReferences || !values) {
        log_error(c, "fmi3GetFloat64: valueReferences or values is NULL.");
        return fmi3Error;
    }
    if (nValues != nValueReferences) {
        log_error(c, "fmi3GetFloat64: nValues = %zu but nValueReferences = %zu (all variables are scalars).",
                  nValues, nValueReferences);
        return fmi3Error;
    }
    for (i = 0; i < nValueReferences; i++) {
        if (valueReferences[i] >= VR_END) {
            log_error(c, "fmi3GetFloat64: unknown value reference %u (valid: 0..%u).", (unsigned)valueReferences[i],
                      VR_END - 1u);
            return fmi3Error;
        }
    }
    for (i = 0; i < nValueReferences; i++) {
        fmi3ValueReference r = valueReferences[i];
        if (r == VR_TIME) {
            values[i] = c->s.time;
        } else if (r < VR_IN0) {
            if (!ensure_outputs(c, "fmi3GetFloat64")) return fmi3Error;
            values[i] = c->y[r - VR_OUT0];
        } else if (r < VR_PAR0) {
            values[i] = c->s.u[r - VR_IN0];
        } else {
            values[i] = c->s.p[r - VR_PAR0];
        }
    }
    return fmi3OK;
}

FMI3_Export fmi3Status fmi3SetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                      size_t nValueReferences, const fmi3Float64 values[], size_t nValues)
{
    size_t i;
    char what[160];
    REQUIRE(instance, SET_MODES, "fmi3SetFloat64");
    if (nValueReferences == 0) return fmi3OK;
    if (!valueReferences || !values) {
        log_error(c, "fmi3SetFloat64: valueReferences or values is NULL.");
        return fmi3Error;
    }
    if (nValues != nValueReferences) {
        log_error(c, "fmi3SetFloat64: nValues = %zu but nValueReferences = %zu (all variables are scalars).",
                  nValues, nValueReferences);
        return fmi3Error;
    }
    for (i = 0; i < nValueReferences; i++) {
        fmi3ValueReference r = valueReferences[i];
        if (r >= VR_END) {
            log_error(c, "fmi3SetFloat64: unknown value reference %u (valid: 0..%u).", (unsigned)r, VR_END - 1u);
            return fmi3Error;
        }
        describe_vr(r, what, sizeof what);
        if (r < VR_IN0) {
            log_error(c, "fmi3SetFloat64: %s cannot be set.", what);
            return fmi3Error;
        }
        if (r >= VR_PAR0 && c->s.mode == MODE_STEP) {
            log_error(c, "fmi3SetFloat64: %s is a fixed parameter: it can only be set before or during "
                         "initialization, not in step mode.",
                      what);
            return fmi3Error;
        }
        if (!isfinite(values[i])) {
            log_error(c, "fmi3SetFloat64: %s: value %g is not finite (NaN/inf rejected).", what, values[i]);
            return fmi3Error;
        }
    }
    for (i = 0; i < nValueReferences; i++) {
        fmi3ValueReference r = valueReferences[i];
        if (r < VR_PAR0) {
            c->s.u[r - VR_IN0] = values[i];
        } else {
            c->s.p[r - VR_PAR0] = values[i];
            c->s.x_ready = 0;
        }
    }
    c->y_valid = 0;
    return fmi3OK;
}

static fmi3Status no_such_type(fmi3Instance instance, const char *fn, size_t nvr, const fmi3ValueReference vr[],
                               int mask)
{
    Instance *c = (Instance *)instance;
    if (!c) return fmi3Error;
    if (!check_mode(c, mask, fn)) return fmi3Error;
    if (nvr == 0) return fmi3OK;
    log_error(c, "%s: unknown value reference %u: this FMU has Float64 variables only.", fn,
              vr ? (unsigned)vr[0] : 0u);
    return fmi3Error;
}

#define GETTER(T, CT)                                                                                    \
    FMI3_Export fmi3Status fmi3Get##T(fmi3Instance instance, const fmi3ValueReference valueReferences[], \
                                      size_t nValueReferences, CT values[], size_t nValues)              \
    {                                                                                                    \
        (void)values;                                                                                    \
        (void)nValues;                                                                                   \
        return no_such_type(instance, "fmi3Get" #T, nValueReferences, valueReferences, GET_MODES);       \
    }
#define SETTER(T, CT)                                                                                    \
    FMI3_Export fmi3Status fmi3Set##T(fmi3Instance instance, const fmi3ValueReference valueReferences[], \
                                      size_t nValueReferences, const CT values[], size_t nValues)        \
    {                                                                                                    \
        (void)values;                                                                                    \
        (void)nValues;                                                                                   \
        return no_such_type(instance, "fmi3Set" #T, nValueReferences, valueReferences, SET_MODES);       \
    }

GETTER(Float32, fmi3Float32)
GETTER(Int8, fmi3Int8)
GETTER(UInt8, fmi3UInt8)
GETTER(Int16, fmi3Int16)
GETTER(UInt16, fmi3UInt16)
GETTER(Int32, fmi3Int32)
GETTER(UInt32, fmi3UInt32)
GETTER(Int64, fmi3Int64)
GETTER(UInt64, fmi3UInt64)
GETTER(Boolean, fmi3Boolean)
GETTER(String, fmi3String)
SETTER(Float32, fmi3Float32)
SETTER(Int8, fmi3Int8)
SETTER(UInt8, fmi3UInt8)
SETTER(Int16, fmi3Int16)
SETTER(UInt16, fmi3UInt16)
SETTER(Int32, fmi3Int32)
SETTER(UInt32, fmi3UInt32)
SETTER(Int64, fmi3Int64)
SETTER(UInt64, fmi3UInt64)
SETTER(Boolean, fmi3Boolean)
SETTER(String, fmi3String)

FMI3_Export fmi3Status fmi3GetBinary(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                     size_t nValueReferences, size_t valueSizes[], fmi3Binary values[],
                                     size_t nValues)
{
    (void)valueSizes;
    (void)values;
    (void)nValues;
    return no_such_type(instance, "fmi3GetBinary", nValueReferences, valueReferences, GET_MODES);
}

FMI3_Export fmi3Status fmi3SetBinary(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                     size_t nValueReferences, const size_t valueSizes[], const fmi3Binary values[],
                                     size_t nValues)
{
    (void)valueSizes;
    (void)values;
    (void)nValues;
    return no_such_type(instance, "fmi3SetBinary", nValueReferences, valueReferences, SET_MODES);
}

FMI3_Export fmi3Status fmi3GetClock(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                    size_t nValueReferences, fmi3Clock values[])
{
    (void)values;
    return no_such_type(instance, "fmi3GetClock", nValueReferences, valueReferences, MODE_ANY);
}

FMI3_Export fmi3Status fmi3SetClock(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                    size_t nValueReferences, const fmi3Clock values[])
{
    (void)values;
    return no_such_type(instance, "fmi3SetClock", nValueReferences, valueReferences, MODE_ANY);
}

/* ---------------------------------------------------- variable dependencies */

FMI3_Export fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance instance, fmi3ValueReference valueReference,
                                                           size_t *nDependencies)
{
    (void)valueReference;
    (void)nDependencies;
    NOT_SUPPORTED(instance, "fmi3GetNumberOfVariableDependencies", "providesPerElementDependencies=false");
}

FMI3_Export fmi3Status fmi3GetVariableDependencies(fmi3Instance instance, fmi3ValueReference dependent,
                                                   size_t elementIndicesOfDependent[],
                                                   fmi3ValueReference independents[],
                                                   size_t elementIndicesOfIndependents[],
                                                   fmi3DependencyKind dependencyKinds[], size_t nDependencies)
{
    (void)dependent;
    (void)elementIndicesOfDependent;
    (void)independents;
    (void)elementIndicesOfIndependents;
    (void)dependencyKinds;
    (void)nDependencies;
    NOT_SUPPORTED(instance, "fmi3GetVariableDependencies", "providesPerElementDependencies=false");
}

/* ---------------------------------------------------------------- FMU state */

static void fill_state(const Instance *c, FmuState *st)
{
    memset(st, 0, sizeof *st);
    memcpy(st->magic, STATE_MAGIC, sizeof st->magic);
    st->version = STATE_VERSION;
    st->nx = SYS_NX;
    st->nu = SYS_NU;
    st->np = SYS_NP;
    st->ny = SYS_NY;
    st->token_hash = c->token_hash;
    st->s = c->s;
}

static int valid_state(Instance *c, const FmuState *st, const char *fn)
{
    if (memcmp(st->magic, STATE_MAGIC, sizeof st->magic) != 0 || st->version != STATE_VERSION) {
        log_error(c, "%s: not an FMU state of this wrapper (bad magic or version).", fn);
        return 0;
    }
    if (st->token_hash != c->token_hash || st->nx != SYS_NX || st->nu != SYS_NU || st->np != SYS_NP ||
        st->ny != SYS_NY) {
        log_error(c, "%s: the FMU state belongs to another FMU (instantiation token or dimensions differ).", fn);
        return 0;
    }
    if (!(st->s.mode & MODE_ANY)) {
        log_error(c, "%s: the FMU state has an invalid mode %d.", fn, (int)st->s.mode);
        return 0;
    }
    return 1;
}

FMI3_Export fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState *FMUState)
{
    FmuState *st;
    REQUIRE(instance, MODE_ANY, "fmi3GetFMUState");
    if (!FMUState) {
        log_error(c, "fmi3GetFMUState: FMUState is NULL.");
        return fmi3Error;
    }
    st = (FmuState *)*FMUState;
    if (!st) {
        st = (FmuState *)calloc(1, sizeof(FmuState));
        if (!st) {
            log_error(c, "fmi3GetFMUState: out of memory.");
            return fmi3Error;
        }
    }
    fill_state(c, st);
    *FMUState = st;
    return fmi3OK;
}

FMI3_Export fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState FMUState)
{
    const FmuState *st = (const FmuState *)FMUState;
    REQUIRE(instance, MODE_ANY, "fmi3SetFMUState");
    if (!st) {
        log_error(c, "fmi3SetFMUState: FMUState is NULL.");
        return fmi3Error;
    }
    if (!valid_state(c, st, "fmi3SetFMUState")) return fmi3Error;
    c->s = st->s;
    c->y_valid = 0;
    return fmi3OK;
}

FMI3_Export fmi3Status fmi3FreeFMUState(fmi3Instance instance, fmi3FMUState *FMUState)
{
    REQUIRE(instance, MODE_ANY, "fmi3FreeFMUState");
    if (!FMUState) {
        log_error(c, "fmi3FreeFMUState: FMUState is NULL.");
        return fmi3Error;
    }
    free(*FMUState);
    *FMUState = NULL;
    return fmi3OK;
}

FMI3_Export fmi3Status fmi3SerializedFMUStateSize(fmi3Instance instance, fmi3FMUState FMUState, size_t *size)
{
    REQUIRE(instance, MODE_ANY, "fmi3SerializedFMUStateSize");
    if (!FMUState || !size) {
        log_error(c, "fmi3SerializedFMUStateSize: FMUState or size is NULL.");
        return fmi3Error;
    }
    *size = sizeof(FmuState);
    return fmi3OK;
}

FMI3_Export fmi3Status fmi3SerializeFMUState(fmi3Instance instance, fmi3FMUState FMUState, fmi3Byte serializedState[],
                                             size_t size)
{
    REQUIRE(instance, MODE_ANY, "fmi3SerializeFMUState");
    if (!FMUState || !serializedState) {
        log_error(c, "fmi3SerializeFMUState: FMUState or serializedState is NULL.");
        return fmi3Error;
    }
    if (size < sizeof(FmuState)) {
        log_error(c, "fmi3SerializeFMUState: buffer of %zu bytes is too small (%zu needed).", size,
                  sizeof(FmuState));
        return fmi3Error;
    }
    memcpy(serializedState, FMUState, sizeof(FmuState));
    return fmi3OK;
}

FMI3_Export fmi3Status fmi3DeserializeFMUState(fmi3Instance instance, const fmi3Byte serializedState[], size_t size,
                                               fmi3FMUState *FMUState)
{
    FmuState tmp, *st;
    REQUIRE(instance, MODE_ANY, "fmi3DeserializeFMUState");
    if (!serializedState || !FMUState) {
        log_error(c, "fmi3DeserializeFMUState: serializedState or FMUState is NULL.");
        return fmi3Error;
    }
    if (size != sizeof(FmuState)) {
        log_error(c, "fmi3DeserializeFMUState: %zu bytes given, a state of this FMU has %zu.", size,
                  sizeof(FmuState));
        return fmi3Error;
    }
    memcpy(&tmp, serializedState, sizeof tmp);
    if (!valid_state(c, &tmp, "fmi3DeserializeFMUState")) return fmi3Error;
    st = (FmuState *)*FMUState;
    if (!st) {
        st = (FmuState *)calloc(1, sizeof(FmuState));
        if (!st) {
            log_error(c, "fmi3DeserializeFMUState: out of memory.");
            return fmi3Error;
        }
    }
    *st = tmp;
    *FMUState = st;
    return fmi3OK;
}

/* ------------------------------------------------------ partial derivatives */

FMI3_Export fmi3Status fmi3GetDirectionalDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[],
                                                    size_t nUnknowns, const fmi3ValueReference knowns[],
                                                    size_t nKnowns, const fmi3Float64 seed[], size_t nSeed,
                                                    fmi3Float64 sensitivity[], size_t nSensitivity)
{
    (void)unknowns;
    (void)nUnknowns;
    (void)knowns;
    (void)nKnowns;
    (void)seed;
    (void)nSeed;
    (void)sensitivity;
    (void)nSensitivity;
    NOT_SUPPORTED(instance, "fmi3GetDirectionalDerivative", "providesDirectionalDerivatives=false");
}

FMI3_Export fmi3Status fmi3GetAdjointDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[],
                                                size_t nUnknowns, const fmi3ValueReference knowns[], size_t nKnowns,
                                                const fmi3Float64 seed[], size_t nSeed, fmi3Float64 sensitivity[],
                                                size_t nSensitivity)
{
    (void)unknowns;
    (void)nUnknowns;
    (void)knowns;
    (void)nKnowns;
    (void)seed;
    (void)nSeed;
    (void)sensitivity;
    (void)nSensitivity;
    NOT_SUPPORTED(instance, "fmi3GetAdjointDerivative", "providesAdjointDerivatives=false");
}

/* ------------------------------------------ configuration mode and clocks */

FMI3_Export fmi3Status fmi3EnterConfigurationMode(fmi3Instance instance)
{
    NOT_SUPPORTED(instance, "fmi3EnterConfigurationMode", "no structural parameters");
}

FMI3_Export fmi3Status fmi3ExitConfigurationMode(fmi3Instance instance)
{
    NOT_SUPPORTED(instance, "fmi3ExitConfigurationMode", "no structural parameters");
}

FMI3_Export fmi3Status fmi3GetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                              size_t nValueReferences, fmi3Float64 intervals[],
                                              fmi3IntervalQualifier qualifiers[])
{
    (void)valueReferences;
    (void)nValueReferences;
    (void)intervals;
    (void)qualifiers;
    NOT_SUPPORTED(instance, "fmi3GetIntervalDecimal", "no clocks");
}

FMI3_Export fmi3Status fmi3GetIntervalFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                               size_t nValueReferences, fmi3UInt64 counters[],
                                               fmi3UInt64 resolutions[], fmi3IntervalQualifier qualifiers[])
{
    (void)valueReferences;
    (void)nValueReferences;
    (void)counters;
    (void)resolutions;
    (void)qualifiers;
    NOT_SUPPORTED(instance, "fmi3GetIntervalFraction", "no clocks");
}

FMI3_Export fmi3Status fmi3GetShiftDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                           size_t nValueReferences, fmi3Float64 shifts[])
{
    (void)valueReferences;
    (void)nValueReferences;
    (void)shifts;
    NOT_SUPPORTED(instance, "fmi3GetShiftDecimal", "no clocks");
}

FMI3_Export fmi3Status fmi3GetShiftFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                            size_t nValueReferences, fmi3UInt64 counters[],
                                            fmi3UInt64 resolutions[])
{
    (void)valueReferences;
    (void)nValueReferences;
    (void)counters;
    (void)resolutions;
    NOT_SUPPORTED(instance, "fmi3GetShiftFraction", "no clocks");
}

FMI3_Export fmi3Status fmi3SetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                              size_t nValueReferences, const fmi3Float64 intervals[])
{
    (void)valueReferences;
    (void)nValueReferences;
    (void)intervals;
    NOT_SUPPORTED(instance, "fmi3SetIntervalDecimal", "no clocks");
}

FMI3_Export fmi3Status fmi3SetIntervalFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                               size_t nValueReferences, const fmi3UInt64 counters[],
                                               const fmi3UInt64 resolutions[])
{
    (void)valueReferences;
    (void)nValueReferences;
    (void)counters;
    (void)resolutions;
    NOT_SUPPORTED(instance, "fmi3SetIntervalFraction", "no clocks");
}

FMI3_Export fmi3Status fmi3SetShiftDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                           size_t nValueReferences, const fmi3Float64 shifts[])
{
    (void)valueReferences;
    (void)nValueReferences;
    (void)shifts;
    NOT_SUPPORTED(instance, "fmi3SetShiftDecimal", "no clocks");
}

FMI3_Export fmi3Status fmi3SetShiftFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                            size_t nValueReferences, const fmi3UInt64 counters[],
                                            const fmi3UInt64 resolutions[])
{
    (void)valueReferences;
    (void)nValueReferences;
    (void)counters;
    (void)resolutions;
    NOT_SUPPORTED(instance, "fmi3SetShiftFraction", "no clocks");
}

FMI3_Export fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance instance)
{
    NOT_SUPPORTED(instance, "fmi3EvaluateDiscreteStates", "hasEventMode=false");
}

FMI3_Export fmi3Status fmi3UpdateDiscreteStates(fmi3Instance instance, fmi3Boolean *discreteStatesNeedUpdate,
                                                fmi3Boolean *terminateSimulation,
                                                fmi3Boolean *nominalsOfContinuousStatesChanged,
                                                fmi3Boolean *valuesOfContinuousStatesChanged,
                                                fmi3Boolean *nextEventTimeDefined, fmi3Float64 *nextEventTime)
{
    (void)discreteStatesNeedUpdate;
    (void)terminateSimulation;
    (void)nominalsOfContinuousStatesChanged;
    (void)valuesOfContinuousStatesChanged;
    (void)nextEventTimeDefined;
    (void)nextEventTime;
    NOT_SUPPORTED(instance, "fmi3UpdateDiscreteStates", "hasEventMode=false");
}

/* ------------------------------------------------- Model Exchange functions */

FMI3_Export fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance instance)
{
    NOT_SUPPORTED(instance, "fmi3EnterContinuousTimeMode", "Model Exchange");
}

FMI3_Export fmi3Status fmi3CompletedIntegratorStep(fmi3Instance instance, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                                   fmi3Boolean *enterEventMode, fmi3Boolean *terminateSimulation)
{
    (void)noSetFMUStatePriorToCurrentPoint;
    (void)enterEventMode;
    (void)terminateSimulation;
    NOT_SUPPORTED(instance, "fmi3CompletedIntegratorStep", "Model Exchange");
}

FMI3_Export fmi3Status fmi3SetTime(fmi3Instance instance, fmi3Float64 time)
{
    (void)time;
    NOT_SUPPORTED(instance, "fmi3SetTime", "Model Exchange");
}

FMI3_Export fmi3Status fmi3SetContinuousStates(fmi3Instance instance, const fmi3Float64 continuousStates[],
                                               size_t nContinuousStates)
{
    (void)continuousStates;
    (void)nContinuousStates;
    NOT_SUPPORTED(instance, "fmi3SetContinuousStates", "Model Exchange");
}

FMI3_Export fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance instance, fmi3Float64 derivatives[],
                                                         size_t nContinuousStates)
{
    (void)derivatives;
    (void)nContinuousStates;
    NOT_SUPPORTED(instance, "fmi3GetContinuousStateDerivatives", "Model Exchange");
}

FMI3_Export fmi3Status fmi3GetEventIndicators(fmi3Instance instance, fmi3Float64 eventIndicators[],
                                              size_t nEventIndicators)
{
    (void)eventIndicators;
    (void)nEventIndicators;
    NOT_SUPPORTED(instance, "fmi3GetEventIndicators", "Model Exchange");
}

FMI3_Export fmi3Status fmi3GetContinuousStates(fmi3Instance instance, fmi3Float64 continuousStates[],
                                               size_t nContinuousStates)
{
    (void)continuousStates;
    (void)nContinuousStates;
    NOT_SUPPORTED(instance, "fmi3GetContinuousStates", "Model Exchange");
}

FMI3_Export fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance instance, fmi3Float64 nominals[],
                                                         size_t nContinuousStates)
{
    (void)nominals;
    (void)nContinuousStates;
    NOT_SUPPORTED(instance, "fmi3GetNominalsOfContinuousStates", "Model Exchange");
}

FMI3_Export fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance instance, size_t *nEventIndicators)
{
    (void)nEventIndicators;
    NOT_SUPPORTED(instance, "fmi3GetNumberOfEventIndicators", "Model Exchange");
}

FMI3_Export fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance instance, size_t *nContinuousStates)
{
    (void)nContinuousStates;
    NOT_SUPPORTED(instance, "fmi3GetNumberOfContinuousStates", "Model Exchange");
}

/* ---------------------------------------------------------------- stepping */

FMI3_Export fmi3Status fmi3EnterStepMode(fmi3Instance instance)
{
    NOT_SUPPORTED(instance, "fmi3EnterStepMode", "hasEventMode=false: fmi3ExitInitializationMode enters Step Mode");
}

FMI3_Export fmi3Status fmi3GetOutputDerivatives(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                                size_t nValueReferences, const fmi3Int32 orders[],
                                                fmi3Float64 values[], size_t nValues)
{
    (void)valueReferences;
    (void)orders;
    (void)values;
    (void)nValues;
    if (nValueReferences == 0 && instance) return fmi3OK;
    NOT_SUPPORTED(instance, "fmi3GetOutputDerivatives", "maxOutputDerivativeOrder=0");
}

FMI3_Export fmi3Status fmi3DoStep(fmi3Instance instance, fmi3Float64 currentCommunicationPoint,
                                  fmi3Float64 communicationStepSize, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                  fmi3Boolean *eventHandlingNeeded, fmi3Boolean *terminateSimulation,
                                  fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime)
{
    const double t = currentCommunicationPoint, h = communicationStepSize;
    double nsteps, x_next[DIM(SYS_NX)];
    CoreState saved;
    long long n, k;
    int rc, bad;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (eventHandlingNeeded) *eventHandlingNeeded = fmi3False;
    if (terminateSimulation) *terminateSimulation = fmi3False;
    if (earlyReturn) *earlyReturn = fmi3False;
    if (lastSuccessfulTime && instance) *lastSuccessfulTime = ((Instance *)instance)->s.time;
    REQUIRE(instance, MODE_STEP, "fmi3DoStep");

    if (!isfinite(t) || !isfinite(h)) {
        log_error(c, "fmi3DoStep: currentCommunicationPoint = %g and communicationStepSize = %g must be finite.", t,
                  h);
        return fmi3Error;
    }
    if (!(h > 0.0)) {
        log_error(c, "fmi3DoStep: communicationStepSize = %g must be > 0.", h);
        return fmi3Error;
    }
    if (fabs(t - c->s.time) > TIME_TOL * (fabs(c->s.time) > 1.0 ? fabs(c->s.time) : 1.0)) {
        log_error(c, "fmi3DoStep: currentCommunicationPoint = %.17g does not match the FMU time %.17g "
                     "(steps must be contiguous; use fmi3SetFMUState to go back).",
                  t, c->s.time);
        return fmi3Error;
    }
    nsteps = h / (double)SYS_STEP;
    if (nsteps > 1e12) {
        log_error(c, "fmi3DoStep: communicationStepSize = %g s is too large (%g internal steps of %g s).", h, nsteps,
                  (double)SYS_STEP);
        return fmi3Error;
    }
    n = (long long)(nsteps + 0.5);
    if (n < 1 || fabs(h - (double)n * (double)SYS_STEP) > STEP_TOL * h) {
        log_error(c, "fmi3DoStep: communicationStepSize = %.17g s is not an integer multiple of the internal "
                     "step %.17g s (ratio %.12g).",
                  h, (double)SYS_STEP, nsteps);
        return fmi3Error;
    }

    saved = c->s;
    for (k = 0; k < n; k++) {
        rc = sys_update(c->s.x, c->s.u, c->s.p, x_next);
        if (rc != 0) {
            log_error(c, "fmi3DoStep: sys_update failed (code %d) at t = %.17g (internal step %lld of %lld); "
                         "the instance stays at t = %.17g.",
                      rc, t + (double)k * (double)SYS_STEP, k + 1, n, t);
            goto fail;
        }
        if (!all_finite(x_next, SYS_NX, &bad)) {
            log_error(c, "fmi3DoStep: state x[%d] became %g (not finite) at t = %.17g (internal step %lld of %lld); "
                         "the instance stays at t = %.17g.",
                      bad, x_next[bad], t + (double)(k + 1) * (double)SYS_STEP, k + 1, n, t);
            goto fail;
        }
        memcpy(c->s.x, x_next, sizeof(double) * (size_t)SYS_NX);
    }
    c->s.time = t + h;
    c->y_valid = 0;
    if (!ensure_outputs(c, "fmi3DoStep")) goto fail;
    if (lastSuccessfulTime) *lastSuccessfulTime = c->s.time;
    return fmi3OK;

fail:
    c->s = saved;
    c->s.mode = MODE_ERROR;
    c->y_valid = 0;
    if (lastSuccessfulTime) *lastSuccessfulTime = c->s.time;
    return fmi3Error;
}

FMI3_Export fmi3Status fmi3ActivateModelPartition(fmi3Instance instance, fmi3ValueReference clockReference,
                                                  fmi3Float64 activationTime)
{
    (void)clockReference;
    (void)activationTime;
    NOT_SUPPORTED(instance, "fmi3ActivateModelPartition", "Scheduled Execution");
}
