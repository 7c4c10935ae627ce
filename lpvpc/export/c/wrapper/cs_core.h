/*
 * cs_core.h -- the FMI-version-independent core of the lpvpc co-simulation wrappers
 * (fmi2_cs.c, fmi3_cs.c) around a fixed-step discrete-time system described by system.h
 * (x(k+1) = f(x, u, p), y = g(x, u, p), x0 = x0(p)).
 *
 * Each wrapper includes this file once and keeps only the FMI API layer: the exported
 * signatures, the mapping of types and status codes, its callbacks and the API names used
 * in messages. Everything here is static, so an FMU stays one translation unit whose binary
 * exports nothing but the fmi2* / fmi3* functions; the header is shipped in sources/ next to
 * the wrapper, so `fmpy compile` rebuilds from the same files.
 *
 * Semantics (FMI 2 and FMI 3)
 *   - direct mode (SYS_TICKS_PER_SAMPLE 0, the default): inputs u are set at communication
 *     point t_k; outputs read at t_k are g(x, u, p) with the current inputs (direct
 *     feedthrough);
 *   - sampled mode (SYS_TICKS_PER_SAMPLE N >= 1): the system is sampled every SYS_STEP s
 *     (sample times t_start + k SYS_STEP); communication steps are integer multiples of the
 *     base tick SYS_STEP / N. A communication step that starts at a sample time processes
 *     that sample with the inputs set at its start (y = g(x, u, p), then x = f(x, u, p));
 *     a longer step processes every later sample it crosses with the same inputs held. The
 *     outputs are those of the last processed sample, held (0 before the first): they do
 *     not depend on the inputs of the current communication point, so every master, whether
 *     it reads outputs before or after setting the next inputs, sees the same values;
 *   - time is kept on the absolute tick grid t_start + i * tick (tick = CS_TICK): the FMU
 *     holds the index i of the tick it is at, never a running sum of step sizes, so masters
 *     that build their times by adding steps cannot make its samples drift;
 *   - DoStep(t_k, h): h > 0, h <= SYS_MAX_STEPS ticks (the declared maximum communication
 *     step, so one call's work is bounded); t_k must be the FMU's time within grid_tolerance
 *     (1e-6 tick per tick elapsed since the start, at least 1e-6 and at most 1e-2 tick), or
 *     round to its current tick (steps are contiguous). An end t_k + h within grid_tolerance of
 *     a grid point is on it: this covers the error of times built by adding steps over long
 *     runs and a last step that is a sliver shorter or longer than whole ticks. The step
 *     processes the grid points from the next unprocessed one up to before its end, each with
 *     the input held (sampled mode: the ticks whose index is a multiple of N process a sample),
 *     then time = t_k + h. A step may end between grid points (a master that steps every
 *     component at one step finer than this FMU's tick): the grid point it started on is
 *     processed with the inputs set at its start, and the outputs are held at that grid
 *     point's values (direct mode: g(x, u) before the update) until the time reaches the next
 *     grid point; inputs set in between are used there unless set again. A step that covers
 *     no grid point (a sliver, which masters that clip their last step produce) only moves
 *     the time. Every state and output is checked finite;
 *     a non-finite value or a failing system function rolls the instance back to
 *     t_k, logs why and returns an error (the instance is then in the error state:
 *     get values / FMU state, set FMU state, reset or free).
 *   - a state given to SetFMUState / DeserializeFMUState is checked field by field (tag,
 *     version, dimensions, GUID, mode, flags, finite time, state, inputs and parameters);
 *   - wrong calls (illegal call sequence, unknown value reference, NaN/inf value,
 *     fixed parameter after initialization, bad step) return an error, log a message
 *     through the logger callback and leave the instance unchanged.
 *   - every instance owns its memory (allocated through the wrapper's cs_alloc);
 *     no mutable global data.
 *
 * Value references: 0 time (FMI 3 only; unknown in FMI 2), outputs 1..NY,
 * inputs NY+1..NY+NU, parameters NY+NU+1..NY+NU+NP, then SYS_NC constant outputs (values
 * SYS_CONST_VALUES, e.g. a declared latency). Units are SI (see modelDescription.xml).
 *
 * The including wrapper defines, before #include "cs_core.h":
 *   CsCallbacks       struct of its importer callbacks (logger, environment, memory), a
 *                     member of every Instance
 *   CsValueReference  its value reference type
 *   CS_HAS_TIME_VR    1 if value reference 0 is the independent variable time, else 0
 *   CS_STATE_MAGIC    8-byte tag of its FMU states (an FMI 2 state is not accepted by an
 *                     FMI 3 binary and vice versa)
 *   CS_REAL_TYPE, CS_VR_ARGS, CS_STATE_ARG, CS_SET_STATE_FN, CS_TOKEN_ARG, CS_TOKEN_NAME
 *                     API names used in log messages (see fmi2_cs.c / fmi3_cs.c)
 * and, after it, the hooks cs_emit, cs_alloc and cs_free declared below.
 */
#ifndef LPVPC_CS_CORE_H
#define LPVPC_CS_CORE_H

#include <math.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include "system.h"

#define DIM(n) ((n) > 0 ? (n) : 1)
#define VR_TIME 0u
#define VR_OUT0 1u
#define VR_IN0 (VR_OUT0 + (unsigned)SYS_NY)
#define VR_PAR0 (VR_IN0 + (unsigned)SYS_NU)
#define VR_CON0 (VR_PAR0 + (unsigned)SYS_NP)
#define VR_END (VR_CON0 + (unsigned)SYS_NC)
#define VR_MIN (CS_HAS_TIME_VR ? VR_TIME : VR_OUT0)

#ifndef SYS_MAX_STEPS
#define SYS_MAX_STEPS 1000000 /* internal steps one doStep may take (the declared maximum step) */
#endif
#ifndef SYS_TICKS_PER_SAMPLE
#define SYS_TICKS_PER_SAMPLE 0 /* direct mode */
#endif
#ifndef SYS_NC
#define SYS_NC 0 /* constant outputs (e.g. the declared latency) */
#define SYS_CONST_VALUES {0.0}
#define SYS_CONST_NAMES {""}
#endif
#ifndef CS_MODEL_EXCHANGE
#define CS_MODEL_EXCHANGE 0 /* 1 in me_core.h: time follows the importer, not the tick grid */
#endif
#define SAMPLED (SYS_TICKS_PER_SAMPLE > 0)
/* the unit of communication steps: the base tick (sampled) or the internal step (direct) */
#define CS_TICK (SAMPLED ? (double)SYS_STEP / (double)SYS_TICKS_PER_SAMPLE : (double)SYS_STEP)
#define TIME_TOL 1e-9 /* relative tolerance on a time (Model Exchange time events) */
#define GRID_TOL_PER_TICK 1e-6 /* tolerance on a communication point, in ticks per tick elapsed */
#define GRID_TOL_MIN 1e-6      /* ... at least this many ticks */
#define GRID_TOL_MAX 1e-2      /* ... at most this many ticks (far below the half tick that rounding needs) */

/* Status of a core operation. The values are those of fmi2Status and fmi3Status, so a wrapper
 * returns them with a cast; CS_STATUS_IS(its OK, Warning, Discard, Error) checks that at compile time. */
typedef enum { CS_OK = 0, CS_WARNING = 1, CS_DISCARD = 2, CS_ERROR = 3 } CsStatus;
#define CS_STATUS_IS(ok, warning, discard, error)                                                        \
    typedef char cs_status_values_match[(CS_OK == (int)(ok) && CS_WARNING == (int)(warning) &&            \
                                         CS_DISCARD == (int)(discard) && CS_ERROR == (int)(error))       \
                                            ? 1                                                          \
                                            : -1]

enum {
    MODE_INSTANTIATED = 1,
    MODE_INIT = 2,
    MODE_STEP = 4,
    MODE_TERMINATED = 8,
    MODE_ERROR = 16
};
#define MODE_ANY (MODE_INSTANTIATED | MODE_INIT | MODE_STEP | MODE_TERMINATED | MODE_ERROR)
#define GET_MODES (MODE_INIT | MODE_STEP | MODE_TERMINATED | MODE_ERROR)
#define SET_MODES (MODE_INSTANTIATED | MODE_INIT | MODE_STEP)

/* Everything an FMU state holds: x, u, p, time, mode. Plain data, memcpy-able. */
typedef struct {
    double x[DIM(SYS_NX)];
    double u[DIM(SYS_NU)];
    double p[DIM(SYS_NP)];
    double time;
    int32_t mode;
    int32_t x_ready; /* x holds x0(p) (before step mode: parameters may still change) */
    double y_held[DIM(SYS_NY)]; /* sampled mode: outputs of the last processed sample */
    int64_t tick;               /* index of the tick the FMU is at: time = t_start + tick * CS_TICK */
    double t_start;             /* start time: tick 0 of the grid (and sample 0 in sampled mode) */
} CoreState;

#define STATE_VERSION 3u

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
    char *name;
    CsCallbacks cb;
} Instance;

#define INSTANCE(handle) ((Instance *)(handle)) /* fmi2Component / fmi3Instance -> Instance */

/* Hooks the wrapper defines after including this file. */
static void cs_emit(const Instance *c, CsStatus status, const char *category, const char *message);
static void *cs_alloc(const Instance *c, size_t size); /* zero-filled; NULL if out of memory */
static void cs_free(const Instance *c, void *p);

static const double param_defaults[DIM(SYS_NP)] = SYS_PARAM_DEFAULTS;
static const double input_defaults[DIM(SYS_NU)] = SYS_INPUT_DEFAULTS;
static const char *const output_names[DIM(SYS_NY)] = SYS_OUTPUT_NAMES;
static const char *const input_names[DIM(SYS_NU)] = SYS_INPUT_NAMES;
static const char *const param_names[DIM(SYS_NP)] = SYS_PARAM_NAMES;
static const double const_values[DIM(SYS_NC)] = SYS_CONST_VALUES;
static const char *const const_names[DIM(SYS_NC)] = SYS_CONST_NAMES;

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

static void vlog(const Instance *c, CsStatus status, const char *category, const char *fmt, va_list ap)
{
    char buf[1024];
    if (!c) return;
    if (status == CS_OK && !c->logging_on) return;
    vsnprintf(buf, sizeof buf, fmt, ap);
    cs_emit(c, status, category, buf);
}

static void log_error(const Instance *c, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vlog(c, CS_ERROR, "logStatusError", fmt, ap);
    va_end(ap);
}

static void log_warning(const Instance *c, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vlog(c, CS_WARNING, "logStatusWarning", fmt, ap);
    va_end(ap);
}

static void log_info(const Instance *c, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vlog(c, CS_OK, "logAll", fmt, ap);
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

/* 1 if c is an instance in one of the modes of mask; else logs the illegal call and returns 0. */
static int check_mode(const Instance *c, int mask, const char *fn)
{
    char allowed[160];
    if (!c) return 0;
    if (c->s.mode & mask) return 1;
    allowed_modes(mask, allowed, sizeof allowed);
    log_error(c, "%s: illegal call sequence: the instance is in %s; allowed in: %s.", fn,
              mode_name(c->s.mode), allowed);
    return 0;
}

/* 1 if VR_MIN <= vr < VR_END (written so that VR_MIN = 0 draws no "always true" warning);
 * else logs the unknown reference and returns 0. */
static int known_vr(const Instance *c, const char *fn, CsValueReference vr)
{
    if ((unsigned)vr - VR_MIN < VR_END - VR_MIN) return 1;
    log_error(c, "%s: unknown value reference %u (valid: %u..%u).", fn, (unsigned)vr, VR_MIN, VR_END - 1u);
    return 0;
}

static void describe_vr(CsValueReference vr, char *buf, size_t n)
{
    if (CS_HAS_TIME_VR && vr == VR_TIME)
        snprintf(buf, n, "independent variable 'time' (vr 0)");
    else if (vr >= VR_OUT0 && vr < VR_IN0)
        snprintf(buf, n, "output '%s' (vr %u)", output_names[vr - VR_OUT0], (unsigned)vr);
    else if (vr >= VR_IN0 && vr < VR_PAR0)
        snprintf(buf, n, "input '%s' (vr %u)", input_names[vr - VR_IN0], (unsigned)vr);
    else if (vr >= VR_PAR0 && vr < VR_CON0)
        snprintf(buf, n, "parameter '%s' (vr %u)", param_names[vr - VR_PAR0], (unsigned)vr);
    else if (vr >= VR_CON0 && vr < VR_END)
        snprintf(buf, n, "constant output '%s' (vr %u)", const_names[vr - VR_CON0], (unsigned)vr);
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
    c->s.t_start = start_time;
    c->s.tick = 0;
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

/* 1 if the time lies between grid points (a step shorter than a tick has ended there): tick is then
 * the index of the next grid point, already processed with the inputs of the one before it. */
static double grid_tolerance(double i);
static int off_grid(const Instance *c)
{
    return !CS_MODEL_EXCHANGE && c->s.mode == MODE_STEP &&
           c->s.time < c->s.t_start + (double)c->s.tick * CS_TICK - grid_tolerance((double)c->s.tick);
}

static int ensure_outputs(Instance *c, const char *fn)
{
    int rc, bad;
    if (c->y_valid) return 1;
    if (!ensure_state(c, fn)) return 0;
    if (SAMPLED || off_grid(c)) { /* held: the last processed sample's (or grid point's) outputs, checked finite */
        memcpy(c->y, c->s.y_held, sizeof c->y);
        c->y_valid = 1;
        return 1;
    }
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

/* ------------------------------------------------------------------ logging */

static CsStatus cs_set_debug_logging(Instance *c, const char *fn, int logging_on, size_t n_categories,
                                     const char *const categories[])
{
    static const char *known[] = {"logStatusError", "logStatusWarning", "logAll"};
    size_t i, k;
    CsStatus status = CS_OK;
    if (!check_mode(c, MODE_ANY, fn)) return CS_ERROR;
    c->logging_on = logging_on ? 1 : 0;
    if (n_categories > 0 && !categories) {
        log_error(c, "%s: categories is NULL but nCategories = %zu.", fn, n_categories);
        return CS_ERROR;
    }
    for (i = 0; i < n_categories; i++) {
        int found = 0;
        for (k = 0; k < sizeof known / sizeof known[0]; k++)
            if (categories[i] && strcmp(categories[i], known[k]) == 0) found = 1;
        if (!found) {
            log_warning(c, "%s: unknown log category '%s' (known: logStatusError, logStatusWarning, logAll).", fn,
                        categories[i] ? categories[i] : "(null)");
            status = CS_WARNING;
        }
    }
    return status;
}

/* ------------------------------------------------- creation and destruction */

/* tmp: a zeroed Instance with only the callbacks (and for FMI 2 the name) set, to log
 * through before the instance exists. */
static int cs_check_name(const Instance *tmp, const char *fn, const char *name)
{
    if (name && name[0]) return 1;
    log_error(tmp, "%s: missing instance name.", fn);
    return 0;
}

static int cs_check_token(const Instance *tmp, const char *fn, const char *token)
{
    if (token && strcmp(token, SYS_GUID) == 0) return 1;
    log_error(tmp, "%s: " CS_TOKEN_ARG " '%s' does not match this binary's " CS_TOKEN_NAME " '%s' "
                   "(modelDescription.xml and binary come from different builds).",
              fn, token ? token : "(null)", SYS_GUID);
    return 0;
}

static Instance *cs_new_instance(const Instance *tmp, const char *fn, const char *name, int logging_on)
{
    size_t len = strlen(name);
    Instance *c = (Instance *)cs_alloc(tmp, sizeof(Instance));
    if (!c) {
        log_error(tmp, "%s: out of memory.", fn);
        return NULL;
    }
    memset(c, 0, sizeof *c);
    c->cb = tmp->cb;
    c->name = (char *)cs_alloc(tmp, len + 1);
    if (!c->name) {
        cs_free(tmp, c);
        log_error(tmp, "%s: out of memory.", fn);
        return NULL;
    }
    memcpy(c->name, name, len + 1);
    c->logging_on = logging_on ? 1 : 0;
    c->token_hash = hash_string(SYS_GUID);
    set_start_values(c, 0.0);
    log_info(c, "%s: %s, %d states, %d inputs, %d outputs, %d parameters, step %g s.", fn, SYS_MODEL_IDENTIFIER,
             SYS_NX, SYS_NU, SYS_NY, SYS_NP, (double)SYS_STEP);
    return c;
}

static void cs_free_instance(Instance *c)
{
    if (!c) return;
    if (c->name) cs_free(c, c->name);
    c->name = NULL;
    cs_free(c, c);
}

/* ------------------------------------------- initialization, termination */

/* Start (and optional stop) time; FMI 2 fmi2SetupExperiment, part of FMI 3 EnterInitializationMode. */
static CsStatus cs_setup_experiment(Instance *c, const char *fn, double start_time, int stop_time_defined,
                                    double stop_time)
{
    if (!check_mode(c, MODE_INSTANTIATED, fn)) return CS_ERROR;
    if (!isfinite(start_time)) {
        log_error(c, "%s: startTime = %g is not finite.", fn, start_time);
        return CS_ERROR;
    }
    if (stop_time_defined && !(stop_time >= start_time)) {
        log_error(c, "%s: stopTime = %g is before startTime = %g.", fn, stop_time, start_time);
        return CS_ERROR;
    }
    c->s.time = start_time;
    c->s.t_start = start_time;
    c->s.tick = 0;
    return CS_OK;
}

static CsStatus cs_enter_initialization(Instance *c, const char *fn)
{
    if (!check_mode(c, MODE_INSTANTIATED, fn)) return CS_ERROR;
    c->s.mode = MODE_INIT;
    return CS_OK;
}

static CsStatus cs_exit_initialization(Instance *c, const char *fn)
{
    if (!check_mode(c, MODE_INIT, fn)) return CS_ERROR;
    if (!ensure_state(c, fn)) return CS_ERROR;
    c->y_valid = 0;
    if (!ensure_outputs(c, fn)) return CS_ERROR;
    c->s.mode = MODE_STEP;
    log_info(c, "%s: step mode at t = %.17g.", fn, c->s.time);
    return CS_OK;
}

static CsStatus cs_terminate(Instance *c, const char *fn)
{
    if (!check_mode(c, MODE_STEP | MODE_ERROR, fn)) return CS_ERROR;
    c->s.mode = MODE_TERMINATED;
    return CS_OK;
}

static CsStatus cs_reset(Instance *c, const char *fn)
{
    if (!check_mode(c, MODE_ANY, fn)) return CS_ERROR;
    set_start_values(c, 0.0);
    log_info(c, "%s: back to the instantiated state with default values.", fn);
    return CS_OK;
}

/* ------------------------------------------------------- getting / setting */

/* Checks common to getting and setting; *done = 1 if the call ends here (returning the status).
 * n_values: FMI 3 passes nValues, FMI 2 (one value per reference) passes n_vr. */
static CsStatus check_access(Instance *c, const char *fn, int mask, const CsValueReference vr[], size_t n_vr,
                             const double values[], size_t n_values, int *done)
{
    *done = 1;
    if (!check_mode(c, mask, fn)) return CS_ERROR;
    if (n_vr == 0) return CS_OK;
    if (!vr || !values) {
        log_error(c, "%s: " CS_VR_ARGS " is NULL.", fn);
        return CS_ERROR;
    }
    if (n_values != n_vr) {
        log_error(c, "%s: nValues = %zu but nValueReferences = %zu (all variables are scalars).", fn, n_values,
                  n_vr);
        return CS_ERROR;
    }
    *done = 0;
    return CS_OK;
}

static CsStatus cs_get_real(Instance *c, const char *fn, const CsValueReference vr[], size_t n_vr, double values[],
                            size_t n_values)
{
    size_t i;
    int done;
    CsStatus st = check_access(c, fn, GET_MODES, vr, n_vr, values, n_values, &done);
    if (done) return st;
    for (i = 0; i < n_vr; i++)
        if (!known_vr(c, fn, vr[i])) return CS_ERROR;
    for (i = 0; i < n_vr; i++) {
        CsValueReference r = vr[i];
        if (CS_HAS_TIME_VR && r == VR_TIME) {
            values[i] = c->s.time;
        } else if (r < VR_IN0) {
            if (!ensure_outputs(c, fn)) return CS_ERROR;
            values[i] = c->y[r - VR_OUT0];
        } else if (r < VR_PAR0) {
            values[i] = c->s.u[r - VR_IN0];
        } else if (r < VR_CON0) {
            values[i] = c->s.p[r - VR_PAR0];
        } else {
            values[i] = const_values[r - VR_CON0];
        }
    }
    return CS_OK;
}

static CsStatus cs_set_real(Instance *c, const char *fn, const CsValueReference vr[], size_t n_vr,
                            const double values[], size_t n_values)
{
    size_t i;
    int done;
    char what[160];
    CsStatus st = check_access(c, fn, SET_MODES, vr, n_vr, values, n_values, &done);
    if (done) return st;
    /* validate everything first: a rejected call changes nothing */
    for (i = 0; i < n_vr; i++) {
        CsValueReference r = vr[i];
        if (!known_vr(c, fn, r)) return CS_ERROR;
        describe_vr(r, what, sizeof what);
        if (r < VR_IN0 || r >= VR_CON0) {
            log_error(c, "%s: %s cannot be set.", fn, what);
            return CS_ERROR;
        }
        if (r >= VR_PAR0 && c->s.mode == MODE_STEP) {
            log_error(c, "%s: %s is a fixed parameter: it can only be set before or during initialization, not "
                         "in step mode.",
                      fn, what);
            return CS_ERROR;
        }
        if (!isfinite(values[i])) {
            log_error(c, "%s: %s: value %g is not finite (NaN/inf rejected).", fn, what, values[i]);
            return CS_ERROR;
        }
    }
    for (i = 0; i < n_vr; i++) {
        CsValueReference r = vr[i];
        if (r < VR_PAR0) {
            c->s.u[r - VR_IN0] = values[i];
        } else {
            c->s.p[r - VR_PAR0] = values[i];
            c->s.x_ready = 0; /* only reachable before step mode */
        }
    }
    c->y_valid = 0;
    return CS_OK;
}

/* Getters and setters of the types this FMU has no variables of. */
static CsStatus cs_no_such_type(Instance *c, const char *fn, int mask, const CsValueReference vr[], size_t n_vr)
{
    if (!check_mode(c, mask, fn)) return CS_ERROR;
    if (n_vr == 0) return CS_OK;
    log_error(c, "%s: unknown value reference %u: this FMU has " CS_REAL_TYPE " variables only.", fn,
              vr ? (unsigned)vr[0] : 0u);
    return CS_ERROR;
}

/* ---------------------------------------------------------------- FMU state */

static void fill_state(const Instance *c, FmuState *st)
{
    memset(st, 0, sizeof *st);
    memcpy(st->magic, CS_STATE_MAGIC, sizeof st->magic);
    st->version = STATE_VERSION;
    st->nx = SYS_NX;
    st->nu = SYS_NU;
    st->np = SYS_NP;
    st->ny = SYS_NY;
    st->token_hash = c->token_hash;
    st->s = c->s;
}

static int valid_state(const Instance *c, const FmuState *st, const char *fn)
{
    int bad;
    const CoreState *s = &st->s;
    if (memcmp(st->magic, CS_STATE_MAGIC, sizeof st->magic) != 0 || st->version != STATE_VERSION) {
        log_error(c, "%s: not an FMU state of this wrapper (bad magic or version).", fn);
        return 0;
    }
    if (st->token_hash != c->token_hash || st->nx != SYS_NX || st->nu != SYS_NU || st->np != SYS_NP ||
        st->ny != SYS_NY || st->pad != 0) {
        log_error(c, "%s: the FMU state belongs to another FMU (" CS_TOKEN_NAME " or dimensions differ).", fn);
        return 0;
    }
    /* A state may come from a file: every field is checked, so that no mode, flag or number
     * reachable through fmi*SetFMUState is one the instance could not have reached itself. */
    if (s->mode != MODE_INSTANTIATED && s->mode != MODE_INIT && s->mode != MODE_STEP && s->mode != MODE_TERMINATED &&
        s->mode != MODE_ERROR) {
        log_error(c, "%s: the FMU state has an invalid mode %d.", fn, (int)s->mode);
        return 0;
    }
    if (s->x_ready != 0 && s->x_ready != 1) {
        log_error(c, "%s: the FMU state has an invalid initial-state flag %d.", fn, (int)s->x_ready);
        return 0;
    }
    if (!s->x_ready && (s->mode & (MODE_STEP | MODE_TERMINATED | MODE_ERROR))) {
        log_error(c, "%s: the FMU state is in %s without an initialized system state.", fn, mode_name(s->mode));
        return 0;
    }
    if (!isfinite(s->time)) {
        log_error(c, "%s: the FMU state's time %g is not finite.", fn, s->time);
        return 0;
    }
    if (s->x_ready && !all_finite(s->x, SYS_NX, &bad)) {
        log_error(c, "%s: the FMU state's system state x[%d] = %g is not finite.", fn, bad, s->x[bad]);
        return 0;
    }
    if (!all_finite(s->u, SYS_NU, &bad)) {
        log_error(c, "%s: the FMU state's input '%s' = %g is not finite.", fn, input_names[bad], s->u[bad]);
        return 0;
    }
    if (!all_finite(s->p, SYS_NP, &bad)) {
        log_error(c, "%s: the FMU state's parameter '%s' = %g is not finite.", fn, param_names[bad], s->p[bad]);
        return 0;
    }
    if (!all_finite(s->y_held, SYS_NY, &bad)) {
        log_error(c, "%s: the FMU state's held output '%s' = %g is not finite.", fn, output_names[bad],
                  s->y_held[bad]);
        return 0;
    }
    if (s->tick < 0 || !isfinite(s->t_start) ||
        (!CS_MODEL_EXCHANGE && (s->time > s->t_start + ((double)s->tick + GRID_TOL_MAX) * CS_TICK ||
                                s->time < s->t_start + ((double)s->tick - 1.0) * CS_TICK))) {
        log_error(c, "%s: the FMU state's tick %lld does not match its time %.17g (start %.17g).", fn,
                  (long long)s->tick, s->time, s->t_start);
        return 0;
    }
    return 1;
}

/* *state if it is set (an FMU state is reused), else a new one; NULL if out of memory. */
static FmuState *state_buffer(const Instance *c, const char *fn, void *const *state)
{
    FmuState *st = (FmuState *)*state;
    if (!st) {
        st = (FmuState *)cs_alloc(c, sizeof(FmuState));
        if (!st) log_error(c, "%s: out of memory.", fn);
    }
    return st;
}

static CsStatus cs_get_state(Instance *c, const char *fn, void **state)
{
    FmuState *st;
    if (!check_mode(c, MODE_ANY, fn)) return CS_ERROR;
    if (!state) {
        log_error(c, "%s: " CS_STATE_ARG " is NULL.", fn);
        return CS_ERROR;
    }
    st = state_buffer(c, fn, state);
    if (!st) return CS_ERROR;
    fill_state(c, st);
    *state = st;
    return CS_OK;
}

static CsStatus cs_set_state(Instance *c, const char *fn, const void *state)
{
    const FmuState *st = (const FmuState *)state;
    if (!check_mode(c, MODE_ANY, fn)) return CS_ERROR;
    if (!st) {
        log_error(c, "%s: " CS_STATE_ARG " is NULL.", fn);
        return CS_ERROR;
    }
    if (!valid_state(c, st, fn)) return CS_ERROR;
    c->s = st->s;
    c->y_valid = 0;
    return CS_OK;
}

static CsStatus cs_free_state(Instance *c, const char *fn, void **state)
{
    if (!check_mode(c, MODE_ANY, fn)) return CS_ERROR;
    if (!state) {
        log_error(c, "%s: " CS_STATE_ARG " is NULL.", fn);
        return CS_ERROR;
    }
    if (*state) cs_free(c, *state);
    *state = NULL;
    return CS_OK;
}

static CsStatus cs_state_size(Instance *c, const char *fn, const void *state, size_t *size)
{
    if (!check_mode(c, MODE_ANY, fn)) return CS_ERROR;
    if (!state || !size) {
        log_error(c, "%s: " CS_STATE_ARG " or size is NULL.", fn);
        return CS_ERROR;
    }
    *size = sizeof(FmuState);
    return CS_OK;
}

static CsStatus cs_serialize_state(Instance *c, const char *fn, const void *state, void *bytes, size_t size)
{
    if (!check_mode(c, MODE_ANY, fn)) return CS_ERROR;
    if (!state || !bytes) {
        log_error(c, "%s: " CS_STATE_ARG " or serializedState is NULL.", fn);
        return CS_ERROR;
    }
    if (size < sizeof(FmuState)) {
        log_error(c, "%s: buffer of %zu bytes is too small (%zu needed).", fn, size, sizeof(FmuState));
        return CS_ERROR;
    }
    memcpy(bytes, state, sizeof(FmuState));
    return CS_OK;
}

static CsStatus cs_deserialize_state(Instance *c, const char *fn, const void *bytes, size_t size, void **state)
{
    FmuState tmp, *st;
    if (!check_mode(c, MODE_ANY, fn)) return CS_ERROR;
    if (!bytes || !state) {
        log_error(c, "%s: serializedState or " CS_STATE_ARG " is NULL.", fn);
        return CS_ERROR;
    }
    if (size != sizeof(FmuState)) {
        log_error(c, "%s: %zu bytes given, a state of this FMU has %zu.", fn, size, sizeof(FmuState));
        return CS_ERROR;
    }
    memcpy(&tmp, bytes, sizeof tmp);
    if (!valid_state(c, &tmp, fn)) return CS_ERROR;
    st = state_buffer(c, fn, state);
    if (!st) return CS_ERROR;
    *st = tmp;
    *state = st;
    return CS_OK;
}

/* ---------------------------------------------------------------- stepping */

/* Tolerance (s) of a communication point near tick index i: grows with the ticks elapsed,
 * as the error of a time built by adding steps does. */
static double grid_tolerance(double i)
{
    double r = GRID_TOL_PER_TICK * (fabs(i) + 1.0);
    if (r < GRID_TOL_MIN) r = GRID_TOL_MIN;
    if (r > GRID_TOL_MAX) r = GRID_TOL_MAX;
    return r * CS_TICK;
}

/* *index = the nearest tick index of t (a double: t may be far off); 1 if t is within the
 * tolerance of that grid point. */
static int grid_index(const Instance *c, double t, double *index)
{
    double i = floor((t - c->s.t_start) / CS_TICK + 0.5);
    *index = i;
    return fabs(t - (c->s.t_start + i * CS_TICK)) <= grid_tolerance(i);
}

static CsStatus cs_do_step(Instance *c, const char *fn, double t, double h)
{
    double x_next[DIM(SYS_NX)], y_new[DIM(SYS_NY)], i0, i1;
    CoreState saved;
    long long n, k;
    int rc, bad, on_grid;
    if (!check_mode(c, MODE_STEP, fn)) return CS_ERROR;

    if (!isfinite(t) || !isfinite(h)) {
        log_error(c, "%s: currentCommunicationPoint = %g and communicationStepSize = %g must be finite.", fn, t, h);
        return CS_ERROR;
    }
    if (!(h > 0.0)) {
        log_error(c, "%s: communicationStepSize = %g must be > 0.", fn, h);
        return CS_ERROR;
    }
    /* contiguous: t is the FMU's time (on the grid or, after a step shorter than a tick, between grid points) */
    if (fabs(t - c->s.time) > grid_tolerance((double)c->s.tick) &&
        !(grid_index(c, t, &i0) && i0 == (double)c->s.tick && !off_grid(c))) {
        log_error(c, "%s: currentCommunicationPoint = %.17g does not match the FMU time %.17g (tick %lld of "
                     "%.17g s from %.17g s; tolerance %.3g s; steps must be contiguous; use " CS_SET_STATE_FN
                     " to go back).",
                  fn, t, c->s.time, (long long)c->s.tick, CS_TICK, c->s.t_start, grid_tolerance((double)c->s.tick));
        return CS_ERROR;
    }
    if (h / CS_TICK > (double)SYS_MAX_STEPS + 0.5) {
        log_error(c, "%s: communicationStepSize = %g s is larger than this FMU's maximum communication step "
                     "%g s (%d steps of %g s; the bound keeps one doStep short).",
                  fn, h, (double)SYS_MAX_STEPS * CS_TICK, SYS_MAX_STEPS, CS_TICK);
        return CS_ERROR;
    }
    /* the step processes the grid points from the next one (tick) up to before its end: a step that ends
     * within the tolerance of a grid point ends on it; one that ends between grid points (a fraction of a
     * tick, for masters that step every component at one finer step) holds the outputs until the next */
    on_grid = grid_index(c, t + h, &i1);
    if (!on_grid) i1 = floor((t + h - c->s.t_start) / CS_TICK) + 1.0;
    i0 = (double)c->s.tick;
    n = i1 > i0 ? (long long)(i1 - i0) : 0;

    saved = c->s;
    for (k = 0; k < n; k++) {
        if (SAMPLED && (c->s.tick + k) % (SAMPLED ? SYS_TICKS_PER_SAMPLE : 1) != 0)
            continue; /* between sample times: nothing to compute */
        if (SAMPLED || (k == n - 1 && !on_grid)) {
            rc = sys_output(c->s.x, c->s.u, c->s.p, y_new);
            if (rc != 0) {
                log_error(c, "%s: sys_output failed (code %d) at the sample time t = %.17g; the instance stays at "
                             "t = %.17g.",
                          fn, rc, t + (double)k * CS_TICK, t);
                goto fail;
            }
            if (!all_finite(y_new, SYS_NY, &bad)) {
                log_error(c, "%s: output '%s' (vr %u) became %g (not finite) at the sample time t = %.17g; the "
                             "instance stays at t = %.17g.",
                          fn, output_names[bad], (unsigned)(VR_OUT0 + bad), y_new[bad], t + (double)k * CS_TICK, t);
                goto fail;
            }
        }
        rc = sys_update(c->s.x, c->s.u, c->s.p, x_next);
        if (rc != 0) {
            log_error(c, "%s: sys_update failed (code %d) at t = %.17g (step %lld of %lld); "
                         "the instance stays at t = %.17g.",
                      fn, rc, t + (double)k * CS_TICK, k + 1, n, t);
            goto fail;
        }
        if (!all_finite(x_next, SYS_NX, &bad)) {
            log_error(c, "%s: state x[%d] became %g (not finite) at t = %.17g (step %lld of %lld); "
                         "the instance stays at t = %.17g.",
                      fn, bad, x_next[bad], t + (double)(k + 1) * CS_TICK, k + 1, n, t);
            goto fail;
        }
        memcpy(c->s.x, x_next, sizeof(double) * (size_t)SYS_NX);
        if (SAMPLED || (k == n - 1 && !on_grid))
            memcpy(c->s.y_held, y_new, sizeof(double) * (size_t)SYS_NY);
    }
    c->s.tick += n;
    c->s.time = t + h;
    c->y_valid = 0;
    if (!ensure_outputs(c, fn)) goto fail;
    return CS_OK;

fail:
    c->s = saved;
    c->s.mode = MODE_ERROR;
    c->y_valid = 0;
    return CS_ERROR;
}

#endif /* LPVPC_CS_CORE_H */
