/*
 * me_core.h -- the FMI-version-independent core of the lpvpc Model Exchange wrappers
 * (fmi2_me.c, fmi3_me.c) around the same fixed-step discrete-time system (system.h) as the
 * co-simulation wrappers: x(k+1) = f(x, u, p), y = g(x, u, p), x0 = x0(p), period T = SYS_STEP.
 *
 * It builds on cs_core.h (instance data, value references, getters/setters and their checks,
 * logging, FMU-state checks) and adds a sampled-data Model Exchange interface: no continuous
 * states, no event indicators, one time event per sample at t_k = t_start + k T.
 *
 * Semantics
 *   - ExitInitializationMode samples the inputs at t_start: y(t_start) = g(x0, u(t_start)).
 *   - at the time event t_k (the importer is in Event Mode at time t_k, its inputs set to
 *     u(t_k)), NewDiscreteStates / UpdateDiscreteStates applies x <- f(x, u_s) (u_s the input
 *     sampled at t_{k-1}), then samples u_s <- u(t_k): y(t_k) = g(x_k, u(t_k)), the same
 *     sequence of values the co-simulation FMU and the numpy prediction give at sample k.
 *     Several elapsed samples (a master that stepped over events) are each applied with the
 *     held input; the time event t_{k+1} is announced as nextEventTime;
 *   - outputs are discrete (they change at the time events only); inputs may be set at any time
 *     after initialization and take effect at the next sample; getting an input returns the value
 *     last set; inputs set at the time of the last sample (to 1e-14 relative, in Event
 *     Mode after the update or in Continuous-Time Mode before time advances) are that sample's
 *     inputs: u(t_k) is the last value given at t_k, so a master that updates its inputs after
 *     the event iteration (OMSimulator) or stops exactly on a sample gets the same samples as one
 *     that sets them before;
 *   - a defined start: if no input was set before ExitInitializationMode, the model rests at x0
 *     until inputs are set; sample 0 is taken at the time they are first set if that is a sample
 *     time, else at the first time event after it (the grid stays t_start + k T);
 *   - SetTime may go past the next time event (integrators probe ahead; nothing depends on time
 *     between events; the samples are applied when Event Mode is entered), never back before the
 *     last sample;
 *   - every state and output is checked finite at each event; a failure rolls the instance back
 *     to before the event, logs why and returns an error (error state, as in co-simulation);
 *   - FMU states hold the core state and the Model Exchange data (live inputs, t_start, k, mode).
 *
 * The including wrapper configures cs_core.h (see there) and then includes this file instead.
 */
#ifndef LPVPC_ME_CORE_H
#define LPVPC_ME_CORE_H

#if defined(__GNUC__)
#pragma GCC diagnostic ignored "-Wunused-function" /* cs_core.h's co-simulation step is not used here */
#endif

#define CS_MODEL_EXCHANGE 1
#include "cs_core.h"

enum { ME_EVENT = 1, ME_CONTINUOUS = 2 };

typedef struct {
    double u_live[DIM(SYS_NU)]; /* inputs as last set (sampled into s.u at the next time event) */
    double t_start;             /* time of sample 0 */
    int64_t k;                  /* index of the last sample taken */
    int32_t submode;            /* ME_EVENT or ME_CONTINUOUS while the core is in MODE_STEP */
    int32_t start;              /* ME_START_*: whether sample 0 has been taken */
} MeData;

/* no input set yet (the model rests at x0); inputs set, sample 0 at the next event; running */
enum { ME_START_NONE = 0, ME_START_PENDING = 1, ME_START_DONE = 2 };

typedef struct {
    Instance core; /* first: an MeInstance is also an Instance */
    MeData me;
} MeInstance;

typedef struct {
    FmuState core;
    MeData me;
} MeFmuState;

#define ME_INSTANCE(handle) ((MeInstance *)(handle))

static double me_sample_time(const MeInstance *m, int64_t k)
{
    return m->me.t_start + (double)k * (double)SYS_STEP;
}

/* relative: inputs set this close to the last sample time are set at that instant (a few ulp, far below TIME_TOL) */
#define ME_INSTANT_TOL 1e-14

static double me_tolerance(double t) { return TIME_TOL * (fabs(t) > 1.0 ? fabs(t) : 1.0); }

static MeInstance *me_new_instance(const Instance *tmp, const char *fn, const char *name, int logging_on)
{
    size_t len = strlen(name);
    MeInstance *m = (MeInstance *)cs_alloc(tmp, sizeof(MeInstance));
    if (!m) {
        log_error(tmp, "%s: out of memory.", fn);
        return NULL;
    }
    memset(m, 0, sizeof *m);
    m->core.cb = tmp->cb;
    m->core.name = (char *)cs_alloc(tmp, len + 1);
    if (!m->core.name) {
        cs_free(tmp, m);
        log_error(tmp, "%s: out of memory.", fn);
        return NULL;
    }
    memcpy(m->core.name, name, len + 1);
    m->core.logging_on = logging_on ? 1 : 0;
    m->core.token_hash = hash_string(SYS_GUID);
    set_start_values(&m->core, 0.0);
    log_info(&m->core, "%s: %s (Model Exchange, time event every %g s), %d states, %d inputs, %d outputs, "
                       "%d parameters.", fn, SYS_MODEL_IDENTIFIER, (double)SYS_STEP, SYS_NX, SYS_NU, SYS_NY, SYS_NP);
    return m;
}

/* 1 if the instance is after initialization in the given Model Exchange submodes; else logs. */
static int me_check_submode(MeInstance *m, int submodes, const char *fn)
{
    if (!check_mode(&m->core, MODE_STEP, fn)) return 0;
    if (m->me.submode & submodes) return 1;
    log_error(&m->core, "%s: illegal call sequence: the instance is in %s; allowed in: %s.", fn,
              m->me.submode == ME_EVENT ? "event mode" : "continuous-time mode",
              submodes == ME_EVENT ? "event mode" : submodes == ME_CONTINUOUS ? "continuous-time mode"
                                                                               : "event or continuous-time mode");
    return 0;
}

static CsStatus me_exit_initialization(MeInstance *m, const char *fn)
{
    Instance *c = &m->core;
    CsStatus st = cs_exit_initialization(c, fn); /* x0(p), y = g(x0, u(t_start)), step mode */
    if (st != CS_OK) return st;
    memcpy(m->me.u_live, c->s.u, sizeof m->me.u_live);
    m->me.t_start = c->s.time;
    m->me.k = 0;
    m->me.submode = ME_EVENT; /* FMI: initialization is left into Event Mode */
    /* inputs set in initialization: sample 0 is at t_start; none set: wait for them (no start-up jump) */
    m->me.start = m->me.start == ME_START_PENDING ? ME_START_DONE : ME_START_NONE;
    return CS_OK;
}

static CsStatus me_reset(MeInstance *m, const char *fn)
{
    CsStatus st = cs_reset(&m->core, fn);
    if (st == CS_OK) memset(&m->me, 0, sizeof m->me);
    return st;
}

static CsStatus me_enter_event_mode(MeInstance *m, const char *fn)
{
    if (!me_check_submode(m, ME_CONTINUOUS, fn)) return CS_ERROR;
    m->me.submode = ME_EVENT;
    return CS_OK;
}

static CsStatus me_enter_continuous_time_mode(MeInstance *m, const char *fn)
{
    if (!me_check_submode(m, ME_EVENT, fn)) return CS_ERROR;
    m->me.submode = ME_CONTINUOUS;
    return CS_OK;
}

static CsStatus me_set_time(MeInstance *m, const char *fn, int submodes, double t)
{
    Instance *c = &m->core;
    double t_last;
    if (!me_check_submode(m, submodes, fn)) return CS_ERROR;
    if (!isfinite(t)) {
        log_error(c, "%s: time %g is not finite.", fn, t);
        return CS_ERROR;
    }
    t_last = me_sample_time(m, m->me.k);
    if (t < t_last - me_tolerance(t_last)) {
        log_error(c, "%s: time %.17g s is before the last sample at %.17g s.", fn, t, t_last);
        return CS_ERROR;
    }
    /* an integrator may probe past the next time event; nothing depends on time between events */
    c->s.time = t;
    return CS_OK;
}

/* Event Mode at the current time: apply the samples that are due; *next_time is the next time event. */
static CsStatus me_update_discrete_states(MeInstance *m, const char *fn, double *next_time)
{
    Instance *c = &m->core;
    CoreState saved = c->s;
    int64_t k0 = m->me.k;
    double x_next[DIM(SYS_NX)];
    int rc, bad;
    if (!me_check_submode(m, ME_EVENT, fn)) return CS_ERROR;
    while (c->s.time >= me_sample_time(m, m->me.k + 1) - me_tolerance(me_sample_time(m, m->me.k + 1))) {
        if (m->me.start != ME_START_DONE) { /* not started: the model rests at x0, the grid goes on */
            m->me.k++;
            continue;
        }
        rc = sys_update(c->s.x, c->s.u, c->s.p, x_next);
        if (rc != 0) {
            log_error(c, "%s: sys_update failed (code %d) at the sample t = %.17g s.", fn, rc,
                      me_sample_time(m, m->me.k + 1));
            goto fail;
        }
        if (!all_finite(x_next, SYS_NX, &bad)) {
            log_error(c, "%s: state x[%d] became %g (not finite) at the sample t = %.17g s.", fn, bad, x_next[bad],
                      me_sample_time(m, m->me.k + 1));
            goto fail;
        }
        memcpy(c->s.x, x_next, sizeof(double) * (size_t)SYS_NX);
        m->me.k++;
    }
    if (m->me.k != k0) {
        memcpy(c->s.u, m->me.u_live, sizeof c->s.u); /* sample the inputs at t_k */
        if (m->me.start == ME_START_PENDING) m->me.start = ME_START_DONE; /* sample 0 */
        c->y_valid = 0;
        if (!ensure_outputs(c, fn)) goto fail;
    }
    if (next_time) *next_time = me_sample_time(m, m->me.k + 1);
    return CS_OK;

fail:
    c->s = saved;
    m->me.k = k0;
    c->s.mode = MODE_ERROR;
    c->y_valid = 0;
    return CS_ERROR;
}

static CsStatus me_completed_integrator_step(MeInstance *m, const char *fn)
{
    return me_check_submode(m, ME_CONTINUOUS, fn) ? CS_OK : CS_ERROR;
}

/* Continuous states, their derivatives and nominals, event indicators: this FMU has none. */
static CsStatus me_no_continuous(MeInstance *m, const char *fn, int mask, size_t n, const char *what)
{
    if (!check_mode(&m->core, mask, fn)) return CS_ERROR;
    if (n == 0) return CS_OK;
    log_error(&m->core, "%s: this FMU has no %s (n = %zu, expected 0).", fn, what, n);
    return CS_ERROR;
}

static int me_sets_an_input(const CsValueReference vr[], size_t n_vr)
{
    size_t i;
    for (i = 0; vr && i < n_vr; i++)
        if (vr[i] >= VR_IN0 && vr[i] < VR_PAR0) return 1;
    return 0;
}

/* Inputs set after initialization wait for the next sample (the core state keeps the sampled ones),
 * unless they are set at the time of the last sample: then they are that sample's inputs. */
static CsStatus me_set_real(MeInstance *m, const char *fn, const CsValueReference vr[], size_t n_vr,
                            const double values[], size_t n_values)
{
    Instance *c = &m->core;
    double sampled[DIM(SYS_NU)];
    double t_last;
    CsStatus st;
    if (c->s.mode != MODE_STEP) {
        st = cs_set_real(c, fn, vr, n_vr, values, n_values);
        if (st == CS_OK && c->s.mode == MODE_INIT && me_sets_an_input(vr, n_vr)) m->me.start = ME_START_PENDING;
        return st;
    }
    memcpy(sampled, c->s.u, sizeof sampled);
    memcpy(c->s.u, m->me.u_live, sizeof sampled);
    st = cs_set_real(c, fn, vr, n_vr, values, n_values);
    memcpy(m->me.u_live, c->s.u, sizeof sampled);
    memcpy(c->s.u, sampled, sizeof sampled);
    if (st != CS_OK || !me_sets_an_input(vr, n_vr)) return st;
    t_last = me_sample_time(m, m->me.k);
    /* the same instant up to the rounding of the time itself: a master's later time (a sliver step after the
     * event) carries an input that has moved on, which belongs to the next sample */
    if (fabs(c->s.time - t_last) <= ME_INSTANT_TOL * (fabs(t_last) > 1.0 ? fabs(t_last) : 1.0)) {
        /* still at the instant t_k (masters that set inputs after the event iteration): u(t_k) is the last value
         * given at t_k, so resample; a model not started yet starts here */
        memcpy(c->s.u, m->me.u_live, sizeof sampled);
        c->y_valid = 0;
        if (!ensure_outputs(c, fn)) {
            memcpy(c->s.u, sampled, sizeof sampled);
            c->s.mode = MODE_ERROR;
            return CS_ERROR;
        }
        m->me.start = ME_START_DONE;
    } else if (m->me.start == ME_START_NONE) {
        m->me.start = ME_START_PENDING; /* sample 0 at the next time event */
    }
    return st;
}

static CsStatus me_get_real(MeInstance *m, const char *fn, const CsValueReference vr[], size_t n_vr,
                            double values[], size_t n_values)
{
    size_t i;
    CsStatus st = cs_get_real(&m->core, fn, vr, n_vr, values, n_values);
    if (st != CS_OK || !(m->core.s.mode & (MODE_STEP | MODE_TERMINATED | MODE_ERROR))) return st;
    for (i = 0; i < n_vr; i++)
        if (vr[i] >= VR_IN0 && vr[i] < VR_PAR0) values[i] = m->me.u_live[vr[i] - VR_IN0];
    return st;
}

/* ---------------------------------------------------------------- FMU state */

static int me_valid_data(const Instance *c, const MeFmuState *st, const char *fn)
{
    int bad;
    const MeData *d = &st->me;
    if (!valid_state(c, &st->core, fn)) return 0;
    if (!isfinite(d->t_start) || d->k < 0 || d->start < ME_START_NONE || d->start > ME_START_DONE ||
        (st->core.s.mode & (MODE_STEP | MODE_TERMINATED | MODE_ERROR) && d->submode != ME_EVENT &&
         d->submode != ME_CONTINUOUS)) {
        log_error(c, "%s: the FMU state's Model Exchange data are invalid.", fn);
        return 0;
    }
    if (!all_finite(d->u_live, SYS_NU, &bad)) {
        log_error(c, "%s: the FMU state's input '%s' = %g is not finite.", fn, input_names[bad], d->u_live[bad]);
        return 0;
    }
    return 1;
}

static CsStatus me_get_state(MeInstance *m, const char *fn, void **state)
{
    MeFmuState *st;
    if (!check_mode(&m->core, MODE_ANY, fn)) return CS_ERROR;
    if (!state) {
        log_error(&m->core, "%s: " CS_STATE_ARG " is NULL.", fn);
        return CS_ERROR;
    }
    st = (MeFmuState *)*state;
    if (!st) st = (MeFmuState *)cs_alloc(&m->core, sizeof(MeFmuState));
    if (!st) {
        log_error(&m->core, "%s: out of memory.", fn);
        return CS_ERROR;
    }
    fill_state(&m->core, &st->core);
    st->me = m->me;
    *state = st;
    return CS_OK;
}

static CsStatus me_set_state(MeInstance *m, const char *fn, const void *state)
{
    const MeFmuState *st = (const MeFmuState *)state;
    if (!check_mode(&m->core, MODE_ANY, fn)) return CS_ERROR;
    if (!st) {
        log_error(&m->core, "%s: " CS_STATE_ARG " is NULL.", fn);
        return CS_ERROR;
    }
    if (!me_valid_data(&m->core, st, fn)) return CS_ERROR;
    m->core.s = st->core.s;
    m->me = st->me;
    m->core.y_valid = 0;
    return CS_OK;
}

static CsStatus me_state_size(MeInstance *m, const char *fn, const void *state, size_t *size)
{
    if (!check_mode(&m->core, MODE_ANY, fn)) return CS_ERROR;
    if (!state || !size) {
        log_error(&m->core, "%s: " CS_STATE_ARG " or size is NULL.", fn);
        return CS_ERROR;
    }
    *size = sizeof(MeFmuState);
    return CS_OK;
}

static CsStatus me_serialize_state(MeInstance *m, const char *fn, const void *state, void *bytes, size_t size)
{
    if (!check_mode(&m->core, MODE_ANY, fn)) return CS_ERROR;
    if (!state || !bytes) {
        log_error(&m->core, "%s: " CS_STATE_ARG " or serializedState is NULL.", fn);
        return CS_ERROR;
    }
    if (size < sizeof(MeFmuState)) {
        log_error(&m->core, "%s: buffer of %zu bytes is too small (%zu needed).", fn, size, sizeof(MeFmuState));
        return CS_ERROR;
    }
    memcpy(bytes, state, sizeof(MeFmuState));
    return CS_OK;
}

static CsStatus me_deserialize_state(MeInstance *m, const char *fn, const void *bytes, size_t size, void **state)
{
    MeFmuState tmp, *st;
    if (!check_mode(&m->core, MODE_ANY, fn)) return CS_ERROR;
    if (!bytes || !state) {
        log_error(&m->core, "%s: serializedState or " CS_STATE_ARG " is NULL.", fn);
        return CS_ERROR;
    }
    if (size != sizeof(MeFmuState)) {
        log_error(&m->core, "%s: %zu bytes given, a serialized state of this FMU has %zu.", fn, size,
                  sizeof(MeFmuState));
        return CS_ERROR;
    }
    memcpy(&tmp, bytes, sizeof tmp);
    if (!me_valid_data(&m->core, &tmp, fn)) return CS_ERROR;
    st = (MeFmuState *)*state;
    if (!st) st = (MeFmuState *)cs_alloc(&m->core, sizeof(MeFmuState));
    if (!st) {
        log_error(&m->core, "%s: out of memory.", fn);
        return CS_ERROR;
    }
    *st = tmp;
    *state = st;
    return CS_OK;
}

#endif /* LPVPC_ME_CORE_H */
