/*
 * fmi2_cs.c -- generic FMI 2.0 co-simulation wrapper for a fixed-step discrete-time
 * system described by system.h (x(k+1) = f(x, u, p), y = g(x, u, p), x0 = x0(p)).
 *
 * Semantics
 *   - inputs u are set at communication point t_k; outputs read at t_k are g(x, u, p)
 *     with the current inputs (direct feedthrough);
 *   - fmi2DoStep(t_k, h): h > 0, |t_k - time| <= 1e-9 * max(1, |time|), h an integer
 *     multiple n of SYS_STEP (relative tolerance 1e-9); applies n updates with the
 *     input held, then time = t_k + h. Every state and output is checked finite;
 *     a non-finite value or a failing system function rolls the instance back to
 *     t_k, logs why and returns fmi2Error (the instance is then in the error state:
 *     get values / FMU state, set FMU state, reset or free).
 *   - wrong calls (illegal call sequence, unknown value reference, NaN/inf value,
 *     fixed parameter after initialization, bad step) return fmi2Error, log a message
 *     through the logger callback and leave the instance unchanged.
 *   - every instance owns its memory (allocated with the importer's allocateMemory);
 *     no mutable global data.
 *
 * Value references: outputs 1..NY, inputs NY+1..NY+NU, parameters NY+NU+1..NY+NU+NP
 * (0 is reserved for time in the FMI 3 wrapper and unused here).
 * Units are SI (see modelDescription.xml).
 */
#include <math.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include "fmi2Functions.h"
#include "system.h"

#define DIM(n) ((n) > 0 ? (n) : 1)
#define VR_OUT0 1u
#define VR_IN0 (VR_OUT0 + (unsigned)SYS_NY)
#define VR_PAR0 (VR_IN0 + (unsigned)SYS_NU)
#define VR_END (VR_PAR0 + (unsigned)SYS_NP)

#define TIME_TOL 1e-9 /* relative tolerance on the communication point */
#define STEP_TOL 1e-9 /* relative tolerance on h being a multiple of SYS_STEP */

enum {
    MODE_INSTANTIATED = 1,
    MODE_INIT = 2,
    MODE_STEP = 4,
    MODE_TERMINATED = 8,
    MODE_ERROR = 16
};
#define MODE_ANY (MODE_INSTANTIATED | MODE_INIT | MODE_STEP | MODE_TERMINATED | MODE_ERROR)

/* Everything an FMU state holds: x, u, p, time, mode. Plain data, memcpy-able. */
typedef struct {
    double x[DIM(SYS_NX)];
    double u[DIM(SYS_NU)];
    double p[DIM(SYS_NP)];
    double time;
    int32_t mode;
    int32_t x_ready; /* x holds x0(p) (before step mode: parameters may still change) */
} CoreState;

#define STATE_MAGIC "LPVPCS2\0"
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
    fmi2CallbackLogger logger;
    fmi2CallbackAllocateMemory allocate;
    fmi2CallbackFreeMemory release;
    fmi2ComponentEnvironment env;
    char *name;
} Instance;

static const double param_defaults[DIM(SYS_NP)] = SYS_PARAM_DEFAULTS;
static const double input_defaults[DIM(SYS_NU)] = SYS_INPUT_DEFAULTS;
static const char *const output_names[DIM(SYS_NY)] = SYS_OUTPUT_NAMES;
static const char *const input_names[DIM(SYS_NU)] = SYS_INPUT_NAMES;
static const char *const param_names[DIM(SYS_NP)] = SYS_PARAM_NAMES;

/* ------------------------------------------------------------------ helpers */

static uint64_t hash_string(const char *s)
{ /* FNV-1a: ties a serialized state to this FMU's GUID */
    uint64_t h = 1469598103934665603ULL;
    while (s && *s) {
        h ^= (unsigned char)*s++;
        h *= 1099511628211ULL;
    }
    return h;
}

static void vlog(Instance *c, fmi2Status status, const char *category, const char *fmt, va_list ap)
{
    char buf[1024], esc[2048];
    size_t i, j = 0;
    if (!c || !c->logger) return;
    if (status == fmi2OK && !c->logging_on) return;
    vsnprintf(buf, sizeof buf, fmt, ap);
    /* the FMI 2 logger treats the message as a printf format: escape '%' */
    for (i = 0; buf[i] && j + 2 < sizeof esc; i++) {
        if (buf[i] == '%') esc[j++] = '%';
        esc[j++] = buf[i];
    }
    esc[j] = '\0';
    c->logger(c->env, c->name, status, category, esc);
}

static void log_error(Instance *c, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vlog(c, fmi2Error, "logStatusError", fmt, ap);
    va_end(ap);
}

static void log_warning(Instance *c, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vlog(c, fmi2Warning, "logStatusWarning", fmt, ap);
    va_end(ap);
}

static void log_info(Instance *c, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vlog(c, fmi2OK, "logAll", fmt, ap);
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

static void describe_vr(fmi2ValueReference vr, char *buf, size_t n)
{
    if (vr >= VR_OUT0 && vr < VR_IN0)
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

/* x0(p) if not yet computed (before step mode). */
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

#define INSTANCE(comp) Instance *c = (Instance *)(comp)
#define REQUIRE(comp, mask, fn)                                                                          \
    INSTANCE(comp);                                                                                      \
    if (!c) return fmi2Error;                                                                            \
    if (!check_mode(c, (mask), (fn))) return fmi2Error

/* ------------------------------------------------------ inquiry and logging */

FMI2_Export const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

FMI2_Export const char *fmi2GetVersion(void) { return fmi2Version; }

FMI2_Export fmi2Status fmi2SetDebugLogging(fmi2Component comp, fmi2Boolean loggingOn, size_t nCategories,
                                           const fmi2String categories[])
{
    static const char *known[] = {"logStatusError", "logStatusWarning", "logAll"};
    size_t i, k;
    fmi2Status status = fmi2OK;
    REQUIRE(comp, MODE_ANY, "fmi2SetDebugLogging");
    c->logging_on = loggingOn ? 1 : 0;
    if (nCategories > 0 && !categories) {
        log_error(c, "fmi2SetDebugLogging: categories is NULL but nCategories = %zu.", nCategories);
        return fmi2Error;
    }
    for (i = 0; i < nCategories; i++) {
        int found = 0;
        for (k = 0; k < sizeof known / sizeof known[0]; k++)
            if (categories[i] && strcmp(categories[i], known[k]) == 0) found = 1;
        if (!found) {
            log_warning(c, "fmi2SetDebugLogging: unknown log category '%s' (known: logStatusError, "
                           "logStatusWarning, logAll).",
                        categories[i] ? categories[i] : "(null)");
            status = fmi2Warning;
        }
    }
    return status;
}

/* ------------------------------------------------- creation and destruction */

FMI2_Export fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                                          fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                                          fmi2Boolean visible, fmi2Boolean loggingOn)
{
    Instance tmp, *c;
    size_t len;
    (void)fmuResourceLocation;
    (void)visible;
    if (!functions || !functions->allocateMemory || !functions->freeMemory) return NULL;
    memset(&tmp, 0, sizeof tmp);
    tmp.logger = functions->logger;
    tmp.env = functions->componentEnvironment;
    tmp.name = (char *)(instanceName ? instanceName : "?");
    if (!instanceName || !instanceName[0]) {
        log_error(&tmp, "fmi2Instantiate: missing instance name.");
        return NULL;
    }
    if (fmuType != fmi2CoSimulation) {
        log_error(&tmp, "fmi2Instantiate: %s supports co-simulation only (fmuType = %d).", SYS_MODEL_IDENTIFIER,
                  (int)fmuType);
        return NULL;
    }
    if (!fmuGUID || strcmp(fmuGUID, SYS_GUID) != 0) {
        log_error(&tmp, "fmi2Instantiate: GUID '%s' does not match this binary's GUID '%s' "
                        "(modelDescription.xml and binary come from different builds).",
                  fmuGUID ? fmuGUID : "(null)", SYS_GUID);
        return NULL;
    }
    c = (Instance *)functions->allocateMemory(1, sizeof(Instance));
    if (!c) {
        log_error(&tmp, "fmi2Instantiate: out of memory.");
        return NULL;
    }
    memset(c, 0, sizeof *c);
    len = strlen(instanceName);
    c->name = (char *)functions->allocateMemory(len + 1, 1);
    if (!c->name) {
        functions->freeMemory(c);
        log_error(&tmp, "fmi2Instantiate: out of memory.");
        return NULL;
    }
    memcpy(c->name, instanceName, len + 1);
    c->logger = functions->logger;
    c->allocate = functions->allocateMemory;
    c->release = functions->freeMemory;
    c->env = functions->componentEnvironment;
    c->logging_on = loggingOn ? 1 : 0;
    c->token_hash = hash_string(SYS_GUID);
    set_start_values(c, 0.0);
    log_info(c, "fmi2Instantiate: %s, %d states, %d inputs, %d outputs, %d parameters, step %g s.",
             SYS_MODEL_IDENTIFIER, SYS_NX, SYS_NU, SYS_NY, SYS_NP, (double)SYS_STEP);
    return (fmi2Component)c;
}

FMI2_Export void fmi2FreeInstance(fmi2Component comp)
{
    INSTANCE(comp);
    fmi2CallbackFreeMemory release;
    if (!c) return;
    release = c->release;
    if (c->name) release(c->name);
    c->name = NULL;
    release(c);
}

/* ------------------------------------------- initialization, termination */

FMI2_Export fmi2Status fmi2SetupExperiment(fmi2Component comp, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                                           fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime)
{
    (void)toleranceDefined;
    (void)tolerance;
    REQUIRE(comp, MODE_INSTANTIATED, "fmi2SetupExperiment");
    if (!isfinite(startTime)) {
        log_error(c, "fmi2SetupExperiment: startTime = %g is not finite.", startTime);
        return fmi2Error;
    }
    if (stopTimeDefined && !(stopTime >= startTime)) {
        log_error(c, "fmi2SetupExperiment: stopTime = %g is before startTime = %g.", stopTime, startTime);
        return fmi2Error;
    }
    c->s.time = startTime;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2EnterInitializationMode(fmi2Component comp)
{
    REQUIRE(comp, MODE_INSTANTIATED, "fmi2EnterInitializationMode");
    c->s.mode = MODE_INIT;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2ExitInitializationMode(fmi2Component comp)
{
    REQUIRE(comp, MODE_INIT, "fmi2ExitInitializationMode");
    if (!ensure_state(c, "fmi2ExitInitializationMode")) return fmi2Error;
    c->y_valid = 0;
    if (!ensure_outputs(c, "fmi2ExitInitializationMode")) return fmi2Error;
    c->s.mode = MODE_STEP;
    log_info(c, "fmi2ExitInitializationMode: step mode at t = %.17g.", c->s.time);
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2Terminate(fmi2Component comp)
{
    REQUIRE(comp, MODE_STEP | MODE_ERROR, "fmi2Terminate");
    c->s.mode = MODE_TERMINATED;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2Reset(fmi2Component comp)
{
    REQUIRE(comp, MODE_ANY, "fmi2Reset");
    set_start_values(c, 0.0);
    log_info(c, "fmi2Reset: back to the instantiated state with default values.");
    return fmi2OK;
}

/* ------------------------------------------------------- getting / setting */

#define GET_MODES (MODE_INIT | MODE_STEP | MODE_TERMINATED | MODE_ERROR)
#define SET_MODES (MODE_INSTANTIATED | MODE_INIT | MODE_STEP)

FMI2_Export fmi2Status fmi2GetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[])
{
    size_t i;
    REQUIRE(comp, GET_MODES, "fmi2GetReal");
    if (nvr == 0) return fmi2OK;
    if (!vr || !value) {
        log_error(c, "fmi2GetReal: vr or value is NULL.");
        return fmi2Error;
    }
    for (i = 0; i < nvr; i++) {
        if (vr[i] < VR_OUT0 || vr[i] >= VR_END) {
            log_error(c, "fmi2GetReal: unknown value reference %u (valid: %u..%u).", (unsigned)vr[i], VR_OUT0,
                      VR_END - 1u);
            return fmi2Error;
        }
    }
    for (i = 0; i < nvr; i++) {
        fmi2ValueReference r = vr[i];
        if (r < VR_IN0) {
            if (!ensure_outputs(c, "fmi2GetReal")) return fmi2Error;
            value[i] = c->y[r - VR_OUT0];
        } else if (r < VR_PAR0) {
            value[i] = c->s.u[r - VR_IN0];
        } else {
            value[i] = c->s.p[r - VR_PAR0];
        }
    }
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2SetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                                   const fmi2Real value[])
{
    size_t i;
    char what[160];
    REQUIRE(comp, SET_MODES, "fmi2SetReal");
    if (nvr == 0) return fmi2OK;
    if (!vr || !value) {
        log_error(c, "fmi2SetReal: vr or value is NULL.");
        return fmi2Error;
    }
    /* validate everything first: a rejected call changes nothing */
    for (i = 0; i < nvr; i++) {
        fmi2ValueReference r = vr[i];
        if (r < VR_OUT0 || r >= VR_END) {
            log_error(c, "fmi2SetReal: unknown value reference %u (valid: %u..%u).", (unsigned)r, VR_OUT0,
                      VR_END - 1u);
            return fmi2Error;
        }
        describe_vr(r, what, sizeof what);
        if (r < VR_IN0) {
            log_error(c, "fmi2SetReal: %s is an output and cannot be set.", what);
            return fmi2Error;
        }
        if (r >= VR_PAR0 && c->s.mode == MODE_STEP) {
            log_error(c, "fmi2SetReal: %s is a fixed parameter: it can only be set before or during "
                         "initialization, not in step mode.",
                      what);
            return fmi2Error;
        }
        if (!isfinite(value[i])) {
            log_error(c, "fmi2SetReal: %s: value %g is not finite (NaN/inf rejected).", what, value[i]);
            return fmi2Error;
        }
    }
    for (i = 0; i < nvr; i++) {
        fmi2ValueReference r = vr[i];
        if (r < VR_PAR0) {
            c->s.u[r - VR_IN0] = value[i];
        } else {
            c->s.p[r - VR_PAR0] = value[i];
            c->s.x_ready = 0; /* only reachable before step mode */
        }
    }
    c->y_valid = 0;
    return fmi2OK;
}

static fmi2Status no_such_type(Instance *c, const char *fn, size_t nvr, const fmi2ValueReference vr[], int mask)
{
    if (!c) return fmi2Error;
    if (!check_mode(c, mask, fn)) return fmi2Error;
    if (nvr == 0) return fmi2OK;
    log_error(c, "%s: unknown value reference %u: this FMU has Real variables only.", fn,
              vr ? (unsigned)vr[0] : 0u);
    return fmi2Error;
}

FMI2_Export fmi2Status fmi2GetInteger(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                                      fmi2Integer value[])
{
    (void)value;
    return no_such_type((Instance *)comp, "fmi2GetInteger", nvr, vr, GET_MODES);
}

FMI2_Export fmi2Status fmi2GetBoolean(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                                      fmi2Boolean value[])
{
    (void)value;
    return no_such_type((Instance *)comp, "fmi2GetBoolean", nvr, vr, GET_MODES);
}

FMI2_Export fmi2Status fmi2GetString(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                                     fmi2String value[])
{
    (void)value;
    return no_such_type((Instance *)comp, "fmi2GetString", nvr, vr, GET_MODES);
}

FMI2_Export fmi2Status fmi2SetInteger(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                                      const fmi2Integer value[])
{
    (void)value;
    return no_such_type((Instance *)comp, "fmi2SetInteger", nvr, vr, SET_MODES);
}

FMI2_Export fmi2Status fmi2SetBoolean(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                                      const fmi2Boolean value[])
{
    (void)value;
    return no_such_type((Instance *)comp, "fmi2SetBoolean", nvr, vr, SET_MODES);
}

FMI2_Export fmi2Status fmi2SetString(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                                     const fmi2String value[])
{
    (void)value;
    return no_such_type((Instance *)comp, "fmi2SetString", nvr, vr, SET_MODES);
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
        log_error(c, "%s: the FMU state belongs to another FMU (GUID or dimensions differ).", fn);
        return 0;
    }
    if (!(st->s.mode & MODE_ANY)) {
        log_error(c, "%s: the FMU state has an invalid mode %d.", fn, (int)st->s.mode);
        return 0;
    }
    return 1;
}

FMI2_Export fmi2Status fmi2GetFMUstate(fmi2Component comp, fmi2FMUstate *FMUstate)
{
    FmuState *st;
    REQUIRE(comp, MODE_ANY, "fmi2GetFMUstate");
    if (!FMUstate) {
        log_error(c, "fmi2GetFMUstate: FMUstate is NULL.");
        return fmi2Error;
    }
    st = (FmuState *)*FMUstate;
    if (!st) {
        st = (FmuState *)c->allocate(1, sizeof(FmuState));
        if (!st) {
            log_error(c, "fmi2GetFMUstate: out of memory.");
            return fmi2Error;
        }
    }
    fill_state(c, st);
    *FMUstate = st;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2SetFMUstate(fmi2Component comp, fmi2FMUstate FMUstate)
{
    const FmuState *st = (const FmuState *)FMUstate;
    REQUIRE(comp, MODE_ANY, "fmi2SetFMUstate");
    if (!st) {
        log_error(c, "fmi2SetFMUstate: FMUstate is NULL.");
        return fmi2Error;
    }
    if (!valid_state(c, st, "fmi2SetFMUstate")) return fmi2Error;
    c->s = st->s;
    c->y_valid = 0;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2FreeFMUstate(fmi2Component comp, fmi2FMUstate *FMUstate)
{
    REQUIRE(comp, MODE_ANY, "fmi2FreeFMUstate");
    if (!FMUstate) {
        log_error(c, "fmi2FreeFMUstate: FMUstate is NULL.");
        return fmi2Error;
    }
    if (*FMUstate) c->release(*FMUstate);
    *FMUstate = NULL;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2SerializedFMUstateSize(fmi2Component comp, fmi2FMUstate FMUstate, size_t *size)
{
    REQUIRE(comp, MODE_ANY, "fmi2SerializedFMUstateSize");
    if (!FMUstate || !size) {
        log_error(c, "fmi2SerializedFMUstateSize: FMUstate or size is NULL.");
        return fmi2Error;
    }
    *size = sizeof(FmuState);
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2SerializeFMUstate(fmi2Component comp, fmi2FMUstate FMUstate, fmi2Byte serializedState[],
                                             size_t size)
{
    REQUIRE(comp, MODE_ANY, "fmi2SerializeFMUstate");
    if (!FMUstate || !serializedState) {
        log_error(c, "fmi2SerializeFMUstate: FMUstate or serializedState is NULL.");
        return fmi2Error;
    }
    if (size < sizeof(FmuState)) {
        log_error(c, "fmi2SerializeFMUstate: buffer of %zu bytes is too small (%zu needed).", size,
                  sizeof(FmuState));
        return fmi2Error;
    }
    memcpy(serializedState, FMUstate, sizeof(FmuState));
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2DeSerializeFMUstate(fmi2Component comp, const fmi2Byte serializedState[], size_t size,
                                               fmi2FMUstate *FMUstate)
{
    FmuState tmp, *st;
    REQUIRE(comp, MODE_ANY, "fmi2DeSerializeFMUstate");
    if (!serializedState || !FMUstate) {
        log_error(c, "fmi2DeSerializeFMUstate: serializedState or FMUstate is NULL.");
        return fmi2Error;
    }
    if (size != sizeof(FmuState)) {
        log_error(c, "fmi2DeSerializeFMUstate: %zu bytes given, a state of this FMU has %zu.", size,
                  sizeof(FmuState));
        return fmi2Error;
    }
    memcpy(&tmp, serializedState, sizeof tmp);
    if (!valid_state(c, &tmp, "fmi2DeSerializeFMUstate")) return fmi2Error;
    st = (FmuState *)*FMUstate;
    if (!st) {
        st = (FmuState *)c->allocate(1, sizeof(FmuState));
        if (!st) {
            log_error(c, "fmi2DeSerializeFMUstate: out of memory.");
            return fmi2Error;
        }
    }
    *st = tmp;
    *FMUstate = st;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2GetDirectionalDerivative(fmi2Component comp, const fmi2ValueReference vUnknown_ref[],
                                                    size_t nUnknown, const fmi2ValueReference vKnown_ref[],
                                                    size_t nKnown, const fmi2Real dvKnown[], fmi2Real dvUnknown[])
{
    (void)vUnknown_ref;
    (void)nUnknown;
    (void)vKnown_ref;
    (void)nKnown;
    (void)dvKnown;
    (void)dvUnknown;
    REQUIRE(comp, MODE_ANY, "fmi2GetDirectionalDerivative");
    log_error(c, "fmi2GetDirectionalDerivative: not supported (providesDirectionalDerivative=false).");
    return fmi2Error;
}

/* ---------------------------------------------------------------- stepping */

FMI2_Export fmi2Status fmi2SetRealInputDerivatives(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                                                   const fmi2Integer order[], const fmi2Real value[])
{
    (void)vr;
    (void)order;
    (void)value;
    REQUIRE(comp, MODE_ANY, "fmi2SetRealInputDerivatives");
    if (nvr == 0) return fmi2OK;
    log_error(c, "fmi2SetRealInputDerivatives: not supported (canInterpolateInputs=false; inputs are held "
                 "constant over a step).");
    return fmi2Error;
}

FMI2_Export fmi2Status fmi2GetRealOutputDerivatives(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                                                    const fmi2Integer order[], fmi2Real value[])
{
    (void)vr;
    (void)order;
    (void)value;
    REQUIRE(comp, MODE_ANY, "fmi2GetRealOutputDerivatives");
    if (nvr == 0) return fmi2OK;
    log_error(c, "fmi2GetRealOutputDerivatives: not supported (maxOutputDerivativeOrder=0).");
    return fmi2Error;
}

FMI2_Export fmi2Status fmi2DoStep(fmi2Component comp, fmi2Real currentCommunicationPoint,
                                  fmi2Real communicationStepSize, fmi2Boolean noSetFMUStatePriorToCurrentPoint)
{
    const double t = currentCommunicationPoint, h = communicationStepSize;
    double nsteps, x_next[DIM(SYS_NX)];
    CoreState saved;
    long long n, k;
    int rc, bad;
    (void)noSetFMUStatePriorToCurrentPoint;
    REQUIRE(comp, MODE_STEP, "fmi2DoStep");

    if (!isfinite(t) || !isfinite(h)) {
        log_error(c, "fmi2DoStep: currentCommunicationPoint = %g and communicationStepSize = %g must be finite.", t,
                  h);
        return fmi2Error;
    }
    if (!(h > 0.0)) {
        log_error(c, "fmi2DoStep: communicationStepSize = %g must be > 0.", h);
        return fmi2Error;
    }
    if (fabs(t - c->s.time) > TIME_TOL * (fabs(c->s.time) > 1.0 ? fabs(c->s.time) : 1.0)) {
        log_error(c, "fmi2DoStep: currentCommunicationPoint = %.17g does not match the FMU time %.17g "
                     "(steps must be contiguous; use fmi2SetFMUstate to go back).",
                  t, c->s.time);
        return fmi2Error;
    }
    nsteps = h / (double)SYS_STEP;
    if (nsteps > 1e12) {
        log_error(c, "fmi2DoStep: communicationStepSize = %g s is too large (%g internal steps of %g s).", h, nsteps,
                  (double)SYS_STEP);
        return fmi2Error;
    }
    n = (long long)(nsteps + 0.5);
    if (n < 1 || fabs(h - (double)n * (double)SYS_STEP) > STEP_TOL * h) {
        log_error(c, "fmi2DoStep: communicationStepSize = %.17g s is not an integer multiple of the internal "
                     "step %.17g s (ratio %.12g).",
                  h, (double)SYS_STEP, nsteps);
        return fmi2Error;
    }

    saved = c->s;
    for (k = 0; k < n; k++) {
        rc = sys_update(c->s.x, c->s.u, c->s.p, x_next);
        if (rc != 0) {
            log_error(c, "fmi2DoStep: sys_update failed (code %d) at t = %.17g (internal step %lld of %lld); "
                         "the instance stays at t = %.17g.",
                      rc, t + (double)k * (double)SYS_STEP, k + 1, n, t);
            goto fail;
        }
        if (!all_finite(x_next, SYS_NX, &bad)) {
            log_error(c, "fmi2DoStep: state x[%d] became %g (not finite) at t = %.17g (internal step %lld of %lld); "
                         "the instance stays at t = %.17g.",
                      bad, x_next[bad], t + (double)(k + 1) * (double)SYS_STEP, k + 1, n, t);
            goto fail;
        }
        memcpy(c->s.x, x_next, sizeof(double) * (size_t)SYS_NX);
    }
    c->s.time = t + h;
    c->y_valid = 0;
    if (!ensure_outputs(c, "fmi2DoStep")) goto fail;
    return fmi2OK;

fail:
    c->s = saved;
    c->s.mode = MODE_ERROR;
    c->y_valid = 0;
    return fmi2Error;
}

FMI2_Export fmi2Status fmi2CancelStep(fmi2Component comp)
{
    REQUIRE(comp, MODE_ANY, "fmi2CancelStep");
    log_error(c, "fmi2CancelStep: not supported (fmi2DoStep is synchronous).");
    return fmi2Error;
}

/* ------------------------------------------------------------------ status */

#define STATUS_MODES (MODE_STEP | MODE_TERMINATED | MODE_ERROR)

FMI2_Export fmi2Status fmi2GetStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Status *value)
{
    REQUIRE(comp, STATUS_MODES, "fmi2GetStatus");
    if (!value) return fmi2Error;
    if (s == fmi2DoStepStatus) {
        *value = c->s.mode == MODE_ERROR ? fmi2Error : fmi2OK;
        return fmi2OK;
    }
    log_error(c, "fmi2GetStatus: status kind %d not available (no asynchronous steps).", (int)s);
    return fmi2Discard;
}

FMI2_Export fmi2Status fmi2GetRealStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Real *value)
{
    REQUIRE(comp, STATUS_MODES, "fmi2GetRealStatus");
    if (!value) return fmi2Error;
    if (s == fmi2LastSuccessfulTime) {
        *value = c->s.time;
        return fmi2OK;
    }
    log_error(c, "fmi2GetRealStatus: status kind %d not available.", (int)s);
    return fmi2Discard;
}

FMI2_Export fmi2Status fmi2GetIntegerStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Integer *value)
{
    (void)value;
    REQUIRE(comp, STATUS_MODES, "fmi2GetIntegerStatus");
    log_error(c, "fmi2GetIntegerStatus: status kind %d not available.", (int)s);
    return fmi2Discard;
}

FMI2_Export fmi2Status fmi2GetBooleanStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Boolean *value)
{
    REQUIRE(comp, STATUS_MODES, "fmi2GetBooleanStatus");
    if (!value) return fmi2Error;
    if (s == fmi2Terminated) {
        *value = fmi2False; /* the FMU never requests termination */
        return fmi2OK;
    }
    log_error(c, "fmi2GetBooleanStatus: status kind %d not available.", (int)s);
    return fmi2Discard;
}

FMI2_Export fmi2Status fmi2GetStringStatus(fmi2Component comp, const fmi2StatusKind s, fmi2String *value)
{
    (void)value;
    REQUIRE(comp, STATUS_MODES, "fmi2GetStringStatus");
    log_error(c, "fmi2GetStringStatus: status kind %d not available.", (int)s);
    return fmi2Discard;
}
