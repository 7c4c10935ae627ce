/*
 * fmi3_cs.c -- generic FMI 3.0 co-simulation wrapper for a fixed-step discrete-time
 * system described by system.h (x(k+1) = f(x, u, p), y = g(x, u, p), x0 = x0(p)).
 *
 * The FMI 3 API layer over cs_core.h, which holds what is shared with fmi2_cs.c: semantics
 * (see there), call-order checks, step and value checks, FMU state and logging. FMI 3 specifics:
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
#include <stdlib.h>

#include "fmi3Functions.h"

typedef fmi3ValueReference CsValueReference;

typedef struct {
    fmi3LogMessageCallback logger;
    fmi3InstanceEnvironment env;
} CsCallbacks;

/* configuration of cs_core.h (see there); the strings are API names for its log messages */
#define CS_HAS_TIME_VR 1
#define CS_STATE_MAGIC "LPVPCS3\0"
#define CS_REAL_TYPE "Float64"
#define CS_VR_ARGS "valueReferences or values"
#define CS_STATE_ARG "FMUState"
#define CS_SET_STATE_FN "fmi3SetFMUState"
#define CS_TOKEN_ARG "instantiationToken"
#define CS_TOKEN_NAME "instantiation token"

#include "cs_core.h"

CS_STATUS_IS(fmi3OK, fmi3Warning, fmi3Discard, fmi3Error);

static void cs_emit(const Instance *c, CsStatus status, const char *category, const char *message)
{
    if (c->cb.logger) c->cb.logger(c->cb.env, (fmi3Status)status, category, message);
}

static void *cs_alloc(const Instance *c, size_t size)
{
    (void)c;
    return calloc(1, size);
}

static void cs_free(const Instance *c, void *p)
{
    (void)c;
    free(p);
}

static fmi3Status not_supported(fmi3Instance instance, const char *fn, const char *why)
{
    Instance *c = INSTANCE(instance);
    if (!c) return fmi3Error;
    log_error(c, "%s: not supported by this co-simulation FMU (%s).", fn, why);
    return fmi3Error;
}

/* ------------------------------------------------------ inquiry and logging */

FMI3_Export const char *fmi3GetVersion(void) { return fmi3Version; }

FMI3_Export fmi3Status fmi3SetDebugLogging(fmi3Instance instance, fmi3Boolean loggingOn, size_t nCategories,
                                           const fmi3String categories[])
{
    return (fmi3Status)cs_set_debug_logging(INSTANCE(instance), "fmi3SetDebugLogging", loggingOn, nCategories,
                                            categories);
}

/* ------------------------------------------------- creation and destruction */

/* Model Exchange and Scheduled Execution instantiation: no instance, and the log says why. */
static fmi3Instance co_simulation_only(const char *fn, fmi3InstanceEnvironment env,
                                       fmi3LogMessageCallback logMessage)
{
    Instance tmp;
    memset(&tmp, 0, sizeof tmp);
    tmp.cb.logger = logMessage;
    tmp.cb.env = env;
    log_error(&tmp, "%s: %s supports co-simulation only.", fn, SYS_MODEL_IDENTIFIER);
    return NULL;
}

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
    return co_simulation_only("fmi3InstantiateModelExchange", instanceEnvironment, logMessage);
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
    return co_simulation_only("fmi3InstantiateScheduledExecution", instanceEnvironment, logMessage);
}

FMI3_Export fmi3Instance fmi3InstantiateCoSimulation(
    fmi3String instanceName, fmi3String instantiationToken, fmi3String resourcePath, fmi3Boolean visible,
    fmi3Boolean loggingOn, fmi3Boolean eventModeUsed, fmi3Boolean earlyReturnAllowed,
    const fmi3ValueReference requiredIntermediateVariables[], size_t nRequiredIntermediateVariables,
    fmi3InstanceEnvironment instanceEnvironment, fmi3LogMessageCallback logMessage,
    fmi3IntermediateUpdateCallback intermediateUpdate)
{
    Instance tmp;
    (void)resourcePath;
    (void)visible;
    (void)eventModeUsed; /* hasEventMode=false: the FMU never needs Event Mode */
    (void)earlyReturnAllowed;
    (void)requiredIntermediateVariables;
    (void)intermediateUpdate;
    memset(&tmp, 0, sizeof tmp);
    tmp.cb.logger = logMessage;
    tmp.cb.env = instanceEnvironment;
    if (!cs_check_name(&tmp, "fmi3InstantiateCoSimulation", instanceName)) return NULL;
    if (!cs_check_token(&tmp, "fmi3InstantiateCoSimulation", instantiationToken)) return NULL;
    if (nRequiredIntermediateVariables > 0) {
        log_error(&tmp, "fmi3InstantiateCoSimulation: intermediate variable access is not supported "
                        "(providesIntermediateUpdate=false).");
        return NULL;
    }
    return (fmi3Instance)cs_new_instance(&tmp, "fmi3InstantiateCoSimulation", instanceName, loggingOn);
}

FMI3_Export void fmi3FreeInstance(fmi3Instance instance) { cs_free_instance(INSTANCE(instance)); }

/* ------------------------------------------- initialization, termination */

FMI3_Export fmi3Status fmi3EnterInitializationMode(fmi3Instance instance, fmi3Boolean toleranceDefined,
                                                   fmi3Float64 tolerance, fmi3Float64 startTime,
                                                   fmi3Boolean stopTimeDefined, fmi3Float64 stopTime)
{
    const char *fn = "fmi3EnterInitializationMode";
    CsStatus st;
    (void)toleranceDefined;
    (void)tolerance;
    st = cs_setup_experiment(INSTANCE(instance), fn, startTime, stopTimeDefined, stopTime);
    if (st == CS_OK) st = cs_enter_initialization(INSTANCE(instance), fn);
    return (fmi3Status)st;
}

FMI3_Export fmi3Status fmi3ExitInitializationMode(fmi3Instance instance)
{
    return (fmi3Status)cs_exit_initialization(INSTANCE(instance), "fmi3ExitInitializationMode");
}

FMI3_Export fmi3Status fmi3EnterEventMode(fmi3Instance instance)
{
    return not_supported(instance, "fmi3EnterEventMode", "hasEventMode=false");
}

FMI3_Export fmi3Status fmi3Terminate(fmi3Instance instance)
{
    return (fmi3Status)cs_terminate(INSTANCE(instance), "fmi3Terminate");
}

FMI3_Export fmi3Status fmi3Reset(fmi3Instance instance)
{
    return (fmi3Status)cs_reset(INSTANCE(instance), "fmi3Reset");
}

/* ------------------------------------------------------- getting / setting */

FMI3_Export fmi3Status fmi3GetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                      size_t nValueReferences, fmi3Float64 values[], size_t nValues)
{
    return (fmi3Status)cs_get_real(INSTANCE(instance), "fmi3GetFloat64", valueReferences, nValueReferences, values,
                                   nValues);
}

FMI3_Export fmi3Status fmi3SetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                      size_t nValueReferences, const fmi3Float64 values[], size_t nValues)
{
    return (fmi3Status)cs_set_real(INSTANCE(instance), "fmi3SetFloat64", valueReferences, nValueReferences, values,
                                   nValues);
}

#include "fmi3_stubs.h" /* types without variables, variable dependencies */

/* ---------------------------------------------------------------- FMU state */

FMI3_Export fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState *FMUState)
{
    return (fmi3Status)cs_get_state(INSTANCE(instance), "fmi3GetFMUState", FMUState);
}

FMI3_Export fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState FMUState)
{
    return (fmi3Status)cs_set_state(INSTANCE(instance), "fmi3SetFMUState", FMUState);
}

FMI3_Export fmi3Status fmi3FreeFMUState(fmi3Instance instance, fmi3FMUState *FMUState)
{
    return (fmi3Status)cs_free_state(INSTANCE(instance), "fmi3FreeFMUState", FMUState);
}

FMI3_Export fmi3Status fmi3SerializedFMUStateSize(fmi3Instance instance, fmi3FMUState FMUState, size_t *size)
{
    return (fmi3Status)cs_state_size(INSTANCE(instance), "fmi3SerializedFMUStateSize", FMUState, size);
}

FMI3_Export fmi3Status fmi3SerializeFMUState(fmi3Instance instance, fmi3FMUState FMUState, fmi3Byte serializedState[],
                                             size_t size)
{
    return (fmi3Status)cs_serialize_state(INSTANCE(instance), "fmi3SerializeFMUState", FMUState, serializedState,
                                          size);
}

FMI3_Export fmi3Status fmi3DeserializeFMUState(fmi3Instance instance, const fmi3Byte serializedState[], size_t size,
                                               fmi3FMUState *FMUState)
{
    return (fmi3Status)cs_deserialize_state(INSTANCE(instance), "fmi3DeserializeFMUState", serializedState, size,
                                            FMUState);
}

/* ------------------------------------------------------ partial derivatives */

/* fmi3GetDirectionalDerivative and fmi3GetAdjointDerivative have the same parameters */
#define NO_DERIVATIVES(name, why)                                                                        \
    FMI3_Export fmi3Status fmi3##name(fmi3Instance instance, const fmi3ValueReference unknowns[],        \
                                      size_t nUnknowns, const fmi3ValueReference knowns[], size_t nKnowns, \
                                      const fmi3Float64 seed[], size_t nSeed, fmi3Float64 sensitivity[],  \
                                      size_t nSensitivity)                                               \
    {                                                                                                    \
        (void)unknowns;                                                                                  \
        (void)nUnknowns;                                                                                 \
        (void)knowns;                                                                                    \
        (void)nKnowns;                                                                                   \
        (void)seed;                                                                                      \
        (void)nSeed;                                                                                     \
        (void)sensitivity;                                                                               \
        (void)nSensitivity;                                                                              \
        return not_supported(instance, "fmi3" #name, why);                                               \
    }

NO_DERIVATIVES(GetDirectionalDerivative, "providesDirectionalDerivatives=false")
NO_DERIVATIVES(GetAdjointDerivative, "providesAdjointDerivatives=false")

/* ------------------------------------------ configuration mode and clocks */

FMI3_Export fmi3Status fmi3EnterConfigurationMode(fmi3Instance instance)
{
    return not_supported(instance, "fmi3EnterConfigurationMode", "no structural parameters");
}

FMI3_Export fmi3Status fmi3ExitConfigurationMode(fmi3Instance instance)
{
    return not_supported(instance, "fmi3ExitConfigurationMode", "no structural parameters");
}

FMI3_Export fmi3Status fmi3GetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                              size_t nValueReferences, fmi3Float64 intervals[],
                                              fmi3IntervalQualifier qualifiers[])
{
    (void)valueReferences;
    (void)nValueReferences;
    (void)intervals;
    (void)qualifiers;
    return not_supported(instance, "fmi3GetIntervalDecimal", "no clocks");
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
    return not_supported(instance, "fmi3GetIntervalFraction", "no clocks");
}

/* Clock functions of the shapes (value references, Float64 array) and (value references, counters,
 * resolutions); CONST is empty for getters. Definitions are checked against fmi3Functions.h. */
#define NO_CLOCK_DECIMAL(name, CONST)                                                                    \
    FMI3_Export fmi3Status fmi3##name(fmi3Instance instance, const fmi3ValueReference valueReferences[], \
                                      size_t nValueReferences, CONST fmi3Float64 values[])               \
    {                                                                                                    \
        (void)valueReferences;                                                                           \
        (void)nValueReferences;                                                                          \
        (void)values;                                                                                    \
        return not_supported(instance, "fmi3" #name, "no clocks");                                       \
    }
#define NO_CLOCK_FRACTION(name, CONST)                                                                   \
    FMI3_Export fmi3Status fmi3##name(fmi3Instance instance, const fmi3ValueReference valueReferences[], \
                                      size_t nValueReferences, CONST fmi3UInt64 counters[],              \
                                      CONST fmi3UInt64 resolutions[])                                    \
    {                                                                                                    \
        (void)valueReferences;                                                                           \
        (void)nValueReferences;                                                                          \
        (void)counters;                                                                                  \
        (void)resolutions;                                                                               \
        return not_supported(instance, "fmi3" #name, "no clocks");                                       \
    }

NO_CLOCK_DECIMAL(GetShiftDecimal, )
NO_CLOCK_DECIMAL(SetIntervalDecimal, const)
NO_CLOCK_DECIMAL(SetShiftDecimal, const)
NO_CLOCK_FRACTION(GetShiftFraction, )
NO_CLOCK_FRACTION(SetIntervalFraction, const)
NO_CLOCK_FRACTION(SetShiftFraction, const)

FMI3_Export fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance instance)
{
    return not_supported(instance, "fmi3EvaluateDiscreteStates", "hasEventMode=false");
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
    return not_supported(instance, "fmi3UpdateDiscreteStates", "hasEventMode=false");
}

/* ------------------------------------------------- Model Exchange functions */

FMI3_Export fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance instance)
{
    return not_supported(instance, "fmi3EnterContinuousTimeMode", "Model Exchange");
}

FMI3_Export fmi3Status fmi3CompletedIntegratorStep(fmi3Instance instance, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                                   fmi3Boolean *enterEventMode, fmi3Boolean *terminateSimulation)
{
    (void)noSetFMUStatePriorToCurrentPoint;
    (void)enterEventMode;
    (void)terminateSimulation;
    return not_supported(instance, "fmi3CompletedIntegratorStep", "Model Exchange");
}

FMI3_Export fmi3Status fmi3SetTime(fmi3Instance instance, fmi3Float64 time)
{
    (void)time;
    return not_supported(instance, "fmi3SetTime", "Model Exchange");
}

/* Model Exchange functions of the shapes (Float64 array, its length) and (count); CONST is empty
 * for getters. Definitions are checked against fmi3Functions.h. */
#define NO_ME_ARRAY(name, CONST)                                                                         \
    FMI3_Export fmi3Status fmi3##name(fmi3Instance instance, CONST fmi3Float64 values[], size_t nValues) \
    {                                                                                                    \
        (void)values;                                                                                    \
        (void)nValues;                                                                                   \
        return not_supported(instance, "fmi3" #name, "Model Exchange");                                  \
    }
#define NO_ME_COUNT(name)                                                                                \
    FMI3_Export fmi3Status fmi3##name(fmi3Instance instance, size_t *n)                                  \
    {                                                                                                    \
        (void)n;                                                                                         \
        return not_supported(instance, "fmi3" #name, "Model Exchange");                                  \
    }

NO_ME_ARRAY(SetContinuousStates, const)
NO_ME_ARRAY(GetContinuousStateDerivatives, )
NO_ME_ARRAY(GetEventIndicators, )
NO_ME_ARRAY(GetContinuousStates, )
NO_ME_ARRAY(GetNominalsOfContinuousStates, )
NO_ME_COUNT(GetNumberOfEventIndicators)
NO_ME_COUNT(GetNumberOfContinuousStates)

/* ---------------------------------------------------------------- stepping */

FMI3_Export fmi3Status fmi3EnterStepMode(fmi3Instance instance)
{
    return not_supported(instance, "fmi3EnterStepMode",
                         "hasEventMode=false: fmi3ExitInitializationMode enters Step Mode");
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
    return not_supported(instance, "fmi3GetOutputDerivatives", "maxOutputDerivativeOrder=0");
}

FMI3_Export fmi3Status fmi3DoStep(fmi3Instance instance, fmi3Float64 currentCommunicationPoint,
                                  fmi3Float64 communicationStepSize, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                  fmi3Boolean *eventHandlingNeeded, fmi3Boolean *terminateSimulation,
                                  fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime)
{
    Instance *c = INSTANCE(instance);
    fmi3Status st;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (eventHandlingNeeded) *eventHandlingNeeded = fmi3False;
    if (terminateSimulation) *terminateSimulation = fmi3False;
    if (earlyReturn) *earlyReturn = fmi3False;
    st = (fmi3Status)cs_do_step(c, "fmi3DoStep", currentCommunicationPoint, communicationStepSize);
    /* t + h after a step, the unchanged (or rolled back) time after an error */
    if (lastSuccessfulTime && c) *lastSuccessfulTime = c->s.time;
    return st;
}

FMI3_Export fmi3Status fmi3ActivateModelPartition(fmi3Instance instance, fmi3ValueReference clockReference,
                                                  fmi3Float64 activationTime)
{
    (void)clockReference;
    (void)activationTime;
    return not_supported(instance, "fmi3ActivateModelPartition", "Scheduled Execution");
}
