/*
 * fmi2_cs.c -- generic FMI 2.0 co-simulation wrapper for a fixed-step discrete-time
 * system described by system.h (x(k+1) = f(x, u, p), y = g(x, u, p), x0 = x0(p)).
 *
 * The FMI 2 API layer over cs_core.h, which holds what is shared with fmi3_cs.c: semantics
 * (see there), call-order checks, step and value checks, FMU state and logging. FMI 2 specifics:
 *   - value reference 0 is unused (FMI 2 has no time variable);
 *   - memory comes from the importer's allocateMemory / freeMemory;
 *   - the logger receives the instance name and treats the message as a printf format;
 *   - fmi2GetStatus, fmi2GetRealStatus and fmi2GetBooleanStatus report the last step's
 *     status, the last successful time and "not terminated"; other kinds are fmi2Discard.
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

/* configuration of cs_core.h (see there); the strings are API names for its log messages */
#define CS_HAS_TIME_VR 0
#define CS_STATE_MAGIC "LPVPCS2\0"
#define CS_REAL_TYPE "Real"
#define CS_VR_ARGS "vr or value"
#define CS_STATE_ARG "FMUstate"
#define CS_SET_STATE_FN "fmi2SetFMUstate"
#define CS_TOKEN_ARG "GUID"
#define CS_TOKEN_NAME "GUID"

#include "cs_core.h"

CS_STATUS_IS(fmi2OK, fmi2Warning, fmi2Discard, fmi2Error);

static void cs_emit(const Instance *c, CsStatus status, const char *category, const char *message)
{
    char esc[2048];
    size_t i, j = 0;
    if (!c->cb.logger) return;
    /* the FMI 2 logger treats the message as a printf format: escape '%' */
    for (i = 0; message[i] && j + 2 < sizeof esc; i++) {
        if (message[i] == '%') esc[j++] = '%';
        esc[j++] = message[i];
    }
    esc[j] = '\0';
    c->cb.logger(c->cb.env, c->name, (fmi2Status)status, category, esc);
}

static void *cs_alloc(const Instance *c, size_t size) { return c->cb.allocate(1, size); }

static void cs_free(const Instance *c, void *p) { c->cb.release(p); }

/* Functions this FMU does not provide: n = 0 is a valid no-op, anything else an error. */
static fmi2Status not_supported(fmi2Component comp, const char *fn, size_t n, const char *why)
{
    Instance *c = INSTANCE(comp);
    if (!check_mode(c, MODE_ANY, fn)) return fmi2Error;
    if (n == 0) return fmi2OK;
    log_error(c, "%s: not supported (%s).", fn, why);
    return fmi2Error;
}

/* ------------------------------------------------------ inquiry and logging */

FMI2_Export const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

FMI2_Export const char *fmi2GetVersion(void) { return fmi2Version; }

FMI2_Export fmi2Status fmi2SetDebugLogging(fmi2Component comp, fmi2Boolean loggingOn, size_t nCategories,
                                           const fmi2String categories[])
{
    return (fmi2Status)cs_set_debug_logging(INSTANCE(comp), "fmi2SetDebugLogging", loggingOn, nCategories,
                                            categories);
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
    if (fmuType != fmi2CoSimulation) {
        log_error(&tmp, "fmi2Instantiate: %s supports co-simulation only (fmuType = %d).", SYS_MODEL_IDENTIFIER,
                  (int)fmuType);
        return NULL;
    }
    if (!cs_check_token(&tmp, "fmi2Instantiate", fmuGUID)) return NULL;
    return (fmi2Component)cs_new_instance(&tmp, "fmi2Instantiate", instanceName, loggingOn);
}

FMI2_Export void fmi2FreeInstance(fmi2Component comp) { cs_free_instance(INSTANCE(comp)); }

/* ------------------------------------------- initialization, termination */

FMI2_Export fmi2Status fmi2SetupExperiment(fmi2Component comp, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                                           fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime)
{
    (void)toleranceDefined;
    (void)tolerance;
    return (fmi2Status)cs_setup_experiment(INSTANCE(comp), "fmi2SetupExperiment", startTime, stopTimeDefined,
                                           stopTime);
}

FMI2_Export fmi2Status fmi2EnterInitializationMode(fmi2Component comp)
{
    return (fmi2Status)cs_enter_initialization(INSTANCE(comp), "fmi2EnterInitializationMode");
}

FMI2_Export fmi2Status fmi2ExitInitializationMode(fmi2Component comp)
{
    return (fmi2Status)cs_exit_initialization(INSTANCE(comp), "fmi2ExitInitializationMode");
}

FMI2_Export fmi2Status fmi2Terminate(fmi2Component comp)
{
    return (fmi2Status)cs_terminate(INSTANCE(comp), "fmi2Terminate");
}

FMI2_Export fmi2Status fmi2Reset(fmi2Component comp) { return (fmi2Status)cs_reset(INSTANCE(comp), "fmi2Reset"); }

/* ------------------------------------------------------- getting / setting */

FMI2_Export fmi2Status fmi2GetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[])
{
    return (fmi2Status)cs_get_real(INSTANCE(comp), "fmi2GetReal", vr, nvr, value, nvr);
}

FMI2_Export fmi2Status fmi2SetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                                   const fmi2Real value[])
{
    return (fmi2Status)cs_set_real(INSTANCE(comp), "fmi2SetReal", vr, nvr, value, nvr);
}

/* the types this FMU has no variables of */
#define GETTER(T)                                                                                         \
    FMI2_Export fmi2Status fmi2Get##T(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,      \
                                      fmi2##T value[])                                                    \
    {                                                                                                     \
        (void)value;                                                                                      \
        return (fmi2Status)cs_no_such_type(INSTANCE(comp), "fmi2Get" #T, GET_MODES, vr, nvr);             \
    }
#define SETTER(T)                                                                                         \
    FMI2_Export fmi2Status fmi2Set##T(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,      \
                                      const fmi2##T value[])                                              \
    {                                                                                                     \
        (void)value;                                                                                      \
        return (fmi2Status)cs_no_such_type(INSTANCE(comp), "fmi2Set" #T, SET_MODES, vr, nvr);             \
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
    return (fmi2Status)cs_get_state(INSTANCE(comp), "fmi2GetFMUstate", FMUstate);
}

FMI2_Export fmi2Status fmi2SetFMUstate(fmi2Component comp, fmi2FMUstate FMUstate)
{
    return (fmi2Status)cs_set_state(INSTANCE(comp), "fmi2SetFMUstate", FMUstate);
}

FMI2_Export fmi2Status fmi2FreeFMUstate(fmi2Component comp, fmi2FMUstate *FMUstate)
{
    return (fmi2Status)cs_free_state(INSTANCE(comp), "fmi2FreeFMUstate", FMUstate);
}

FMI2_Export fmi2Status fmi2SerializedFMUstateSize(fmi2Component comp, fmi2FMUstate FMUstate, size_t *size)
{
    return (fmi2Status)cs_state_size(INSTANCE(comp), "fmi2SerializedFMUstateSize", FMUstate, size);
}

FMI2_Export fmi2Status fmi2SerializeFMUstate(fmi2Component comp, fmi2FMUstate FMUstate, fmi2Byte serializedState[],
                                             size_t size)
{
    return (fmi2Status)cs_serialize_state(INSTANCE(comp), "fmi2SerializeFMUstate", FMUstate, serializedState, size);
}

FMI2_Export fmi2Status fmi2DeSerializeFMUstate(fmi2Component comp, const fmi2Byte serializedState[], size_t size,
                                               fmi2FMUstate *FMUstate)
{
    return (fmi2Status)cs_deserialize_state(INSTANCE(comp), "fmi2DeSerializeFMUstate", serializedState, size,
                                            FMUstate);
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
    return not_supported(comp, "fmi2GetDirectionalDerivative", 1, "providesDirectionalDerivative=false");
}

/* ---------------------------------------------------------------- stepping */

FMI2_Export fmi2Status fmi2SetRealInputDerivatives(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                                                   const fmi2Integer order[], const fmi2Real value[])
{
    (void)vr;
    (void)order;
    (void)value;
    return not_supported(comp, "fmi2SetRealInputDerivatives", nvr,
                         "canInterpolateInputs=false; inputs are held constant over a step");
}

FMI2_Export fmi2Status fmi2GetRealOutputDerivatives(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                                                    const fmi2Integer order[], fmi2Real value[])
{
    (void)vr;
    (void)order;
    (void)value;
    return not_supported(comp, "fmi2GetRealOutputDerivatives", nvr, "maxOutputDerivativeOrder=0");
}

FMI2_Export fmi2Status fmi2DoStep(fmi2Component comp, fmi2Real currentCommunicationPoint,
                                  fmi2Real communicationStepSize, fmi2Boolean noSetFMUStatePriorToCurrentPoint)
{
    (void)noSetFMUStatePriorToCurrentPoint;
    return (fmi2Status)cs_do_step(INSTANCE(comp), "fmi2DoStep", currentCommunicationPoint, communicationStepSize);
}

FMI2_Export fmi2Status fmi2CancelStep(fmi2Component comp)
{
    return not_supported(comp, "fmi2CancelStep", 1, "fmi2DoStep is synchronous");
}

/* ------------------------------------------------------------------ status */

#define STATUS_MODES (MODE_STEP | MODE_TERMINATED | MODE_ERROR)
#define NO_KIND (-1)

/* Common part of the fmi2Get*Status functions, each of which provides at most one status kind
 * (NO_KIND: none): fmi2OK if the caller is to fill *value, else the status to return. */
static fmi2Status status_query(fmi2Component comp, const char *fn, fmi2StatusKind s, int provided, const void *value)
{
    Instance *c = INSTANCE(comp);
    if (!check_mode(c, STATUS_MODES, fn)) return fmi2Error;
    if (provided != NO_KIND) {
        if (!value) return fmi2Error;
        if ((int)s == provided) return fmi2OK;
    }
    /* fmi2DoStepStatus is the one kind of fmi2GetStatus; the others concern asynchronous steps */
    log_error(c, "%s: status kind %d not available%s.", fn, (int)s,
              provided == (int)fmi2DoStepStatus ? " (no asynchronous steps)" : "");
    return fmi2Discard;
}

FMI2_Export fmi2Status fmi2GetStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Status *value)
{
    fmi2Status st = status_query(comp, "fmi2GetStatus", s, fmi2DoStepStatus, value);
    if (st == fmi2OK) *value = INSTANCE(comp)->s.mode == MODE_ERROR ? fmi2Error : fmi2OK;
    return st;
}

FMI2_Export fmi2Status fmi2GetRealStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Real *value)
{
    fmi2Status st = status_query(comp, "fmi2GetRealStatus", s, fmi2LastSuccessfulTime, value);
    if (st == fmi2OK) *value = INSTANCE(comp)->s.time;
    return st;
}

FMI2_Export fmi2Status fmi2GetIntegerStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Integer *value)
{
    (void)value;
    return status_query(comp, "fmi2GetIntegerStatus", s, NO_KIND, NULL);
}

FMI2_Export fmi2Status fmi2GetBooleanStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Boolean *value)
{
    fmi2Status st = status_query(comp, "fmi2GetBooleanStatus", s, fmi2Terminated, value);
    if (st == fmi2OK) *value = fmi2False; /* the FMU never requests termination */
    return st;
}

FMI2_Export fmi2Status fmi2GetStringStatus(fmi2Component comp, const fmi2StatusKind s, fmi2String *value)
{
    (void)value;
    return status_query(comp, "fmi2GetStringStatus", s, NO_KIND, NULL);
}
