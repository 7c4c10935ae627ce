/*
 * fmi2_me.c -- generic FMI 2.0 Model Exchange wrapper for a fixed-step discrete-time system
 * described by system.h, as a sampled-data model with one time event per sample (me_core.h:
 * semantics; cs_core.h: value references, checks, logging).
 *
 * No continuous states, no event indicators. After fmi2ExitInitializationMode the instance is in
 * Event Mode; fmi2NewDiscreteStates at a sample time applies the sample and announces the next
 * one (nextEventTimeDefined, nextEventTime). FMI 2 specifics as in fmi2_cs.c (memory callbacks,
 * printf-style logger, value reference 0 unused).
 *
 * Value references: outputs 1..NY, inputs NY+1..NY+NU, parameters NY+NU+1..NY+NU+NP.
 * Units are SI (see modelDescription.xml).
 */
#include "fmi2Functions.h"

typedef fmi2ValueReference CsValueReference;

typedef struct {
    fmi2CallbackLogger logger;
    fmi2CallbackAllocateMemory allocate;
    fmi2CallbackFreeMemory release;
    fmi2ComponentEnvironment env;
} CsCallbacks;

/* configuration of cs_core.h (see there) */
#define CS_HAS_TIME_VR 0
#define CS_STATE_MAGIC "LPVPME2\0"
#define CS_REAL_TYPE "Real"
#define CS_VR_ARGS "vr or value"
#define CS_STATE_ARG "FMUstate"
#define CS_SET_STATE_FN "fmi2SetFMUstate"
#define CS_TOKEN_ARG "GUID"
#define CS_TOKEN_NAME "GUID"

#include "me_core.h"

CS_STATUS_IS(fmi2OK, fmi2Warning, fmi2Discard, fmi2Error);

static void cs_emit(const Instance *c, CsStatus status, const char *category, const char *message)
{
    char esc[2048];
    size_t i, j = 0;
    if (!c->cb.logger) return;
    for (i = 0; message[i] && j + 2 < sizeof esc; i++) { /* the logger takes a printf format */
        if (message[i] == '%') esc[j++] = '%';
        esc[j++] = message[i];
    }
    esc[j] = '\0';
    c->cb.logger(c->cb.env, c->name, (fmi2Status)status, category, esc);
}

static void *cs_alloc(const Instance *c, size_t size) { return c->cb.allocate(1, size); }

static void cs_free(const Instance *c, void *p) { c->cb.release(p); }

#define M(comp) ME_INSTANCE(comp)
#define C(comp) INSTANCE(comp)

/* ------------------------------------------------------ inquiry and logging */

FMI2_Export const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

FMI2_Export const char *fmi2GetVersion(void) { return fmi2Version; }

FMI2_Export fmi2Status fmi2SetDebugLogging(fmi2Component comp, fmi2Boolean loggingOn, size_t nCategories,
                                           const fmi2String categories[])
{
    return (fmi2Status)cs_set_debug_logging(C(comp), "fmi2SetDebugLogging", loggingOn, nCategories, categories);
}

/* ------------------------------------------------- creation and destruction */

FMI2_Export fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                                          fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                                          fmi2Boolean visible, fmi2Boolean loggingOn)
{
    Instance tmp;
    (void)fmuResourceLocation;
    (void)visible;
    if (!functions || !functions->allocateMemory || !functions->freeMemory) return NULL;
    memset(&tmp, 0, sizeof tmp);
    tmp.cb.logger = functions->logger;
    tmp.cb.allocate = functions->allocateMemory;
    tmp.cb.release = functions->freeMemory;
    tmp.cb.env = functions->componentEnvironment;
    tmp.name = (char *)(instanceName ? instanceName : "?");
    if (!cs_check_name(&tmp, "fmi2Instantiate", instanceName)) return NULL;
    if (fmuType != fmi2ModelExchange) {
        log_error(&tmp, "fmi2Instantiate: %s supports Model Exchange only (fmuType = %d).", SYS_MODEL_IDENTIFIER,
                  (int)fmuType);
        return NULL;
    }
    if (!cs_check_token(&tmp, "fmi2Instantiate", fmuGUID)) return NULL;
    return (fmi2Component)me_new_instance(&tmp, "fmi2Instantiate", instanceName, loggingOn);
}

FMI2_Export void fmi2FreeInstance(fmi2Component comp) { cs_free_instance(C(comp)); }

/* ------------------------------------------- initialization, termination */

FMI2_Export fmi2Status fmi2SetupExperiment(fmi2Component comp, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                                           fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime)
{
    (void)toleranceDefined;
    (void)tolerance;
    return (fmi2Status)cs_setup_experiment(C(comp), "fmi2SetupExperiment", startTime, stopTimeDefined, stopTime);
}

FMI2_Export fmi2Status fmi2EnterInitializationMode(fmi2Component comp)
{
    return (fmi2Status)cs_enter_initialization(C(comp), "fmi2EnterInitializationMode");
}

FMI2_Export fmi2Status fmi2ExitInitializationMode(fmi2Component comp)
{
    return (fmi2Status)me_exit_initialization(M(comp), "fmi2ExitInitializationMode");
}

FMI2_Export fmi2Status fmi2Terminate(fmi2Component comp)
{
    return (fmi2Status)cs_terminate(C(comp), "fmi2Terminate");
}

FMI2_Export fmi2Status fmi2Reset(fmi2Component comp) { return (fmi2Status)me_reset(M(comp), "fmi2Reset"); }

/* ------------------------------------------------------- getting / setting */

FMI2_Export fmi2Status fmi2GetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[])
{
    return (fmi2Status)me_get_real(M(comp), "fmi2GetReal", vr, nvr, value, nvr);
}

FMI2_Export fmi2Status fmi2SetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                                   const fmi2Real value[])
{
    return (fmi2Status)me_set_real(M(comp), "fmi2SetReal", vr, nvr, value, nvr);
}

#define GETTER(T)                                                                                         \
    FMI2_Export fmi2Status fmi2Get##T(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,      \
                                      fmi2##T value[])                                                    \
    {                                                                                                     \
        (void)value;                                                                                      \
        return (fmi2Status)cs_no_such_type(C(comp), "fmi2Get" #T, GET_MODES, vr, nvr);                    \
    }
#define SETTER(T)                                                                                         \
    FMI2_Export fmi2Status fmi2Set##T(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,      \
                                      const fmi2##T value[])                                              \
    {                                                                                                     \
        (void)value;                                                                                      \
        return (fmi2Status)cs_no_such_type(C(comp), "fmi2Set" #T, SET_MODES, vr, nvr);                    \
    }

GETTER(Integer)
GETTER(Boolean)
GETTER(String)
SETTER(Integer)
SETTER(Boolean)
SETTER(String)

/* ---------------------------------------------------------------- FMU state */

FMI2_Export fmi2Status fmi2GetFMUstate(fmi2Component comp, fmi2FMUstate *FMUstate)
{
    return (fmi2Status)me_get_state(M(comp), "fmi2GetFMUstate", FMUstate);
}

FMI2_Export fmi2Status fmi2SetFMUstate(fmi2Component comp, fmi2FMUstate FMUstate)
{
    return (fmi2Status)me_set_state(M(comp), "fmi2SetFMUstate", FMUstate);
}

FMI2_Export fmi2Status fmi2FreeFMUstate(fmi2Component comp, fmi2FMUstate *FMUstate)
{
    return (fmi2Status)cs_free_state(C(comp), "fmi2FreeFMUstate", FMUstate);
}

FMI2_Export fmi2Status fmi2SerializedFMUstateSize(fmi2Component comp, fmi2FMUstate FMUstate, size_t *size)
{
    return (fmi2Status)me_state_size(M(comp), "fmi2SerializedFMUstateSize", FMUstate, size);
}

FMI2_Export fmi2Status fmi2SerializeFMUstate(fmi2Component comp, fmi2FMUstate FMUstate, fmi2Byte serializedState[],
                                             size_t size)
{
    return (fmi2Status)me_serialize_state(M(comp), "fmi2SerializeFMUstate", FMUstate, serializedState, size);
}

FMI2_Export fmi2Status fmi2DeSerializeFMUstate(fmi2Component comp, const fmi2Byte serializedState[], size_t size,
                                               fmi2FMUstate *FMUstate)
{
    return (fmi2Status)me_deserialize_state(M(comp), "fmi2DeSerializeFMUstate", serializedState, size, FMUstate);
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
    if (!check_mode(C(comp), MODE_ANY, "fmi2GetDirectionalDerivative")) return fmi2Error;
    log_error(C(comp), "fmi2GetDirectionalDerivative: not supported (providesDirectionalDerivative=false).");
    return fmi2Error;
}

/* ------------------------------------------------------------ Model Exchange */

FMI2_Export fmi2Status fmi2EnterEventMode(fmi2Component comp)
{
    return (fmi2Status)me_enter_event_mode(M(comp), "fmi2EnterEventMode");
}

FMI2_Export fmi2Status fmi2NewDiscreteStates(fmi2Component comp, fmi2EventInfo *eventInfo)
{
    double next = 0.0;
    fmi2Status st;
    if (!eventInfo) {
        if (check_mode(C(comp), MODE_ANY, "fmi2NewDiscreteStates"))
            log_error(C(comp), "fmi2NewDiscreteStates: eventInfo is NULL.");
        return fmi2Error;
    }
    st = (fmi2Status)me_update_discrete_states(M(comp), "fmi2NewDiscreteStates", &next);
    eventInfo->newDiscreteStatesNeeded = fmi2False;
    eventInfo->terminateSimulation = fmi2False;
    eventInfo->nominalsOfContinuousStatesChanged = fmi2False;
    eventInfo->valuesOfContinuousStatesChanged = fmi2False;
    eventInfo->nextEventTimeDefined = st == fmi2OK ? fmi2True : fmi2False;
    eventInfo->nextEventTime = next;
    return st;
}

FMI2_Export fmi2Status fmi2EnterContinuousTimeMode(fmi2Component comp)
{
    return (fmi2Status)me_enter_continuous_time_mode(M(comp), "fmi2EnterContinuousTimeMode");
}

FMI2_Export fmi2Status fmi2CompletedIntegratorStep(fmi2Component comp, fmi2Boolean noSetFMUStatePriorToCurrentPoint,
                                                   fmi2Boolean *enterEventMode, fmi2Boolean *terminateSimulation)
{
    fmi2Status st;
    (void)noSetFMUStatePriorToCurrentPoint;
    st = (fmi2Status)me_completed_integrator_step(M(comp), "fmi2CompletedIntegratorStep");
    if (enterEventMode) *enterEventMode = fmi2False; /* time events only: the importer knows them */
    if (terminateSimulation) *terminateSimulation = fmi2False;
    return st;
}

FMI2_Export fmi2Status fmi2SetTime(fmi2Component comp, fmi2Real time)
{
    return (fmi2Status)me_set_time(M(comp), "fmi2SetTime", ME_EVENT | ME_CONTINUOUS, time);
}

#define ME_MODES (MODE_INIT | MODE_STEP | MODE_TERMINATED | MODE_ERROR)

FMI2_Export fmi2Status fmi2SetContinuousStates(fmi2Component comp, const fmi2Real x[], size_t nx)
{
    (void)x;
    return (fmi2Status)me_no_continuous(M(comp), "fmi2SetContinuousStates", MODE_STEP, nx, "continuous states");
}

FMI2_Export fmi2Status fmi2GetDerivatives(fmi2Component comp, fmi2Real derivatives[], size_t nx)
{
    (void)derivatives;
    return (fmi2Status)me_no_continuous(M(comp), "fmi2GetDerivatives", ME_MODES, nx, "continuous states");
}

FMI2_Export fmi2Status fmi2GetEventIndicators(fmi2Component comp, fmi2Real eventIndicators[], size_t ni)
{
    (void)eventIndicators;
    return (fmi2Status)me_no_continuous(M(comp), "fmi2GetEventIndicators", ME_MODES, ni, "event indicators");
}

FMI2_Export fmi2Status fmi2GetContinuousStates(fmi2Component comp, fmi2Real x[], size_t nx)
{
    (void)x;
    return (fmi2Status)me_no_continuous(M(comp), "fmi2GetContinuousStates", ME_MODES, nx, "continuous states");
}

FMI2_Export fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component comp, fmi2Real x_nominal[], size_t nx)
{
    (void)x_nominal;
    return (fmi2Status)me_no_continuous(M(comp), "fmi2GetNominalsOfContinuousStates", ME_MODES, nx,
                                        "continuous states");
}
