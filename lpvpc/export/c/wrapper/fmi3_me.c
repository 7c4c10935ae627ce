/*
 * fmi3_me.c -- generic FMI 3.0 Model Exchange wrapper for a fixed-step discrete-time system
 * described by system.h, as a sampled-data model with one time event per sample (me_core.h:
 * semantics; cs_core.h: value references, checks, logging).
 *
 * No continuous states, no event indicators, no clocks. fmi3ExitInitializationMode leaves the
 * instance in Event Mode; fmi3UpdateDiscreteStates at a sample time applies the sample and
 * announces the next one (nextEventTimeDefined, nextEventTime). Co-simulation and Scheduled
 * Execution instantiation return NULL with a log message. Memory comes from malloc/free.
 *
 * Value references: 0 time, outputs 1..NY, inputs NY+1..NY+NU, parameters NY+NU+1..NY+NU+NP.
 * Units are SI (see modelDescription.xml).
 */
#include <stdlib.h>

#include "fmi3Functions.h"

typedef fmi3ValueReference CsValueReference;

typedef struct {
    fmi3LogMessageCallback logger;
    fmi3InstanceEnvironment env;
} CsCallbacks;

/* configuration of cs_core.h (see there) */
#define CS_HAS_TIME_VR 1
#define CS_STATE_MAGIC "LPVPME3\0"
#define CS_REAL_TYPE "Float64"
#define CS_VR_ARGS "valueReferences or values"
#define CS_STATE_ARG "FMUState"
#define CS_SET_STATE_FN "fmi3SetFMUState"
#define CS_TOKEN_ARG "instantiationToken"
#define CS_TOKEN_NAME "instantiation token"

#include "me_core.h"

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
    log_error(c, "%s: not supported by this Model Exchange FMU (%s).", fn, why);
    return fmi3Error;
}

#define M(instance) ME_INSTANCE(instance)

/* ------------------------------------------------------ inquiry and logging */

FMI3_Export const char *fmi3GetVersion(void) { return fmi3Version; }

FMI3_Export fmi3Status fmi3SetDebugLogging(fmi3Instance instance, fmi3Boolean loggingOn, size_t nCategories,
                                           const fmi3String categories[])
{
    return (fmi3Status)cs_set_debug_logging(INSTANCE(instance), "fmi3SetDebugLogging", loggingOn, nCategories,
                                            categories);
}

/* ------------------------------------------------- creation and destruction */

static fmi3Instance model_exchange_only(const char *fn, fmi3InstanceEnvironment env, fmi3LogMessageCallback logMessage)
{
    Instance tmp;
    memset(&tmp, 0, sizeof tmp);
    tmp.cb.logger = logMessage;
    tmp.cb.env = env;
    log_error(&tmp, "%s: %s supports Model Exchange only.", fn, SYS_MODEL_IDENTIFIER);
    return NULL;
}

FMI3_Export fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                                      fmi3String resourcePath, fmi3Boolean visible,
                                                      fmi3Boolean loggingOn, fmi3InstanceEnvironment instanceEnvironment,
                                                      fmi3LogMessageCallback logMessage)
{
    Instance tmp;
    (void)resourcePath;
    (void)visible;
    memset(&tmp, 0, sizeof tmp);
    tmp.cb.logger = logMessage;
    tmp.cb.env = instanceEnvironment;
    if (!cs_check_name(&tmp, "fmi3InstantiateModelExchange", instanceName)) return NULL;
    if (!cs_check_token(&tmp, "fmi3InstantiateModelExchange", instantiationToken)) return NULL;
    return (fmi3Instance)me_new_instance(&tmp, "fmi3InstantiateModelExchange", instanceName, loggingOn);
}

FMI3_Export fmi3Instance fmi3InstantiateCoSimulation(
    fmi3String instanceName, fmi3String instantiationToken, fmi3String resourcePath, fmi3Boolean visible,
    fmi3Boolean loggingOn, fmi3Boolean eventModeUsed, fmi3Boolean earlyReturnAllowed,
    const fmi3ValueReference requiredIntermediateVariables[], size_t nRequiredIntermediateVariables,
    fmi3InstanceEnvironment instanceEnvironment, fmi3LogMessageCallback logMessage,
    fmi3IntermediateUpdateCallback intermediateUpdate)
{
    (void)instanceName;
    (void)instantiationToken;
    (void)resourcePath;
    (void)visible;
    (void)loggingOn;
    (void)eventModeUsed;
    (void)earlyReturnAllowed;
    (void)requiredIntermediateVariables;
    (void)nRequiredIntermediateVariables;
    (void)intermediateUpdate;
    return model_exchange_only("fmi3InstantiateCoSimulation", instanceEnvironment, logMessage);
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
    return model_exchange_only("fmi3InstantiateScheduledExecution", instanceEnvironment, logMessage);
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
    return (fmi3Status)me_exit_initialization(M(instance), "fmi3ExitInitializationMode");
}

FMI3_Export fmi3Status fmi3EnterEventMode(fmi3Instance instance)
{
    return (fmi3Status)me_enter_event_mode(M(instance), "fmi3EnterEventMode");
}

FMI3_Export fmi3Status fmi3Terminate(fmi3Instance instance)
{
    return (fmi3Status)cs_terminate(INSTANCE(instance), "fmi3Terminate");
}

FMI3_Export fmi3Status fmi3Reset(fmi3Instance instance) { return (fmi3Status)me_reset(M(instance), "fmi3Reset"); }

/* ------------------------------------------------------- getting / setting */

FMI3_Export fmi3Status fmi3GetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                      size_t nValueReferences, fmi3Float64 values[], size_t nValues)
{
    return (fmi3Status)me_get_real(M(instance), "fmi3GetFloat64", valueReferences, nValueReferences, values, nValues);
}

FMI3_Export fmi3Status fmi3SetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                      size_t nValueReferences, const fmi3Float64 values[], size_t nValues)
{
    return (fmi3Status)me_set_real(M(instance), "fmi3SetFloat64", valueReferences, nValueReferences, values, nValues);
}

#include "fmi3_stubs.h" /* types without variables, variable dependencies */

/* ---------------------------------------------------------------- FMU state */

FMI3_Export fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState *FMUState)
{
    return (fmi3Status)me_get_state(M(instance), "fmi3GetFMUState", FMUState);
}

FMI3_Export fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState FMUState)
{
    return (fmi3Status)me_set_state(M(instance), "fmi3SetFMUState", FMUState);
}

FMI3_Export fmi3Status fmi3FreeFMUState(fmi3Instance instance, fmi3FMUState *FMUState)
{
    return (fmi3Status)cs_free_state(INSTANCE(instance), "fmi3FreeFMUState", FMUState);
}

FMI3_Export fmi3Status fmi3SerializedFMUStateSize(fmi3Instance instance, fmi3FMUState FMUState, size_t *size)
{
    return (fmi3Status)me_state_size(M(instance), "fmi3SerializedFMUStateSize", FMUState, size);
}

FMI3_Export fmi3Status fmi3SerializeFMUState(fmi3Instance instance, fmi3FMUState FMUState, fmi3Byte serializedState[],
                                             size_t size)
{
    return (fmi3Status)me_serialize_state(M(instance), "fmi3SerializeFMUState", FMUState, serializedState, size);
}

FMI3_Export fmi3Status fmi3DeserializeFMUState(fmi3Instance instance, const fmi3Byte serializedState[], size_t size,
                                               fmi3FMUState *FMUState)
{
    return (fmi3Status)me_deserialize_state(M(instance), "fmi3DeserializeFMUState", serializedState, size,
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
    return not_supported(instance, "fmi3EvaluateDiscreteStates", "providesEvaluateDiscreteStates=false");
}

/* ------------------------------------------------------------ Model Exchange */

FMI3_Export fmi3Status fmi3UpdateDiscreteStates(fmi3Instance instance, fmi3Boolean *discreteStatesNeedUpdate,
                                                fmi3Boolean *terminateSimulation,
                                                fmi3Boolean *nominalsOfContinuousStatesChanged,
                                                fmi3Boolean *valuesOfContinuousStatesChanged,
                                                fmi3Boolean *nextEventTimeDefined, fmi3Float64 *nextEventTime)
{
    double next = 0.0;
    fmi3Status st = (fmi3Status)me_update_discrete_states(M(instance), "fmi3UpdateDiscreteStates", &next);
    if (discreteStatesNeedUpdate) *discreteStatesNeedUpdate = fmi3False;
    if (terminateSimulation) *terminateSimulation = fmi3False;
    if (nominalsOfContinuousStatesChanged) *nominalsOfContinuousStatesChanged = fmi3False;
    if (valuesOfContinuousStatesChanged) *valuesOfContinuousStatesChanged = fmi3False;
    if (nextEventTimeDefined) *nextEventTimeDefined = st == fmi3OK ? fmi3True : fmi3False;
    if (nextEventTime) *nextEventTime = next;
    return st;
}

FMI3_Export fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance instance)
{
    return (fmi3Status)me_enter_continuous_time_mode(M(instance), "fmi3EnterContinuousTimeMode");
}

FMI3_Export fmi3Status fmi3CompletedIntegratorStep(fmi3Instance instance, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                                   fmi3Boolean *enterEventMode, fmi3Boolean *terminateSimulation)
{
    fmi3Status st;
    (void)noSetFMUStatePriorToCurrentPoint;
    st = (fmi3Status)me_completed_integrator_step(M(instance), "fmi3CompletedIntegratorStep");
    if (enterEventMode) *enterEventMode = fmi3False; /* time events only: the importer knows them */
    if (terminateSimulation) *terminateSimulation = fmi3False;
    return st;
}

FMI3_Export fmi3Status fmi3SetTime(fmi3Instance instance, fmi3Float64 time)
{
    return (fmi3Status)me_set_time(M(instance), "fmi3SetTime", ME_CONTINUOUS, time);
}

#define ME_MODES (MODE_INIT | MODE_STEP | MODE_TERMINATED | MODE_ERROR)

FMI3_Export fmi3Status fmi3SetContinuousStates(fmi3Instance instance, const fmi3Float64 values[], size_t nValues)
{
    (void)values;
    return (fmi3Status)me_no_continuous(M(instance), "fmi3SetContinuousStates", MODE_STEP, nValues,
                                        "continuous states");
}

/* getters of the continuous part this FMU does not have: n = 0 only */
#define NO_CONTINUOUS(name, what)                                                                        \
    FMI3_Export fmi3Status fmi3##name(fmi3Instance instance, fmi3Float64 values[], size_t nValues)       \
    {                                                                                                    \
        (void)values;                                                                                    \
        return (fmi3Status)me_no_continuous(M(instance), "fmi3" #name, ME_MODES, nValues, what);         \
    }

NO_CONTINUOUS(GetContinuousStateDerivatives, "continuous states")
NO_CONTINUOUS(GetEventIndicators, "event indicators")
NO_CONTINUOUS(GetContinuousStates, "continuous states")
NO_CONTINUOUS(GetNominalsOfContinuousStates, "continuous states")

#define COUNT_ZERO(name)                                                                                 \
    FMI3_Export fmi3Status fmi3##name(fmi3Instance instance, size_t *n)                                  \
    {                                                                                                    \
        if (!check_mode(INSTANCE(instance), MODE_ANY, "fmi3" #name)) return fmi3Error;                   \
        if (!n) {                                                                                        \
            log_error(INSTANCE(instance), "fmi3" #name ": the output argument is NULL.");                \
            return fmi3Error;                                                                            \
        }                                                                                                \
        *n = 0;                                                                                          \
        return fmi3OK;                                                                                   \
    }

COUNT_ZERO(GetNumberOfEventIndicators)
COUNT_ZERO(GetNumberOfContinuousStates)

/* ------------------------------------- co-simulation and scheduled execution */
/* Not this FMU's interface type; exported (as errors) because importers bind every fmi3 function. */

FMI3_Export fmi3Status fmi3EnterStepMode(fmi3Instance instance)
{
    return not_supported(instance, "fmi3EnterStepMode", "co-simulation");
}

FMI3_Export fmi3Status fmi3GetOutputDerivatives(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                                size_t nValueReferences, const fmi3Int32 orders[],
                                                fmi3Float64 values[], size_t nValues)
{
    (void)valueReferences;
    (void)nValueReferences;
    (void)orders;
    (void)values;
    (void)nValues;
    return not_supported(instance, "fmi3GetOutputDerivatives", "co-simulation");
}

FMI3_Export fmi3Status fmi3DoStep(fmi3Instance instance, fmi3Float64 currentCommunicationPoint,
                                  fmi3Float64 communicationStepSize, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                  fmi3Boolean *eventHandlingNeeded, fmi3Boolean *terminateSimulation,
                                  fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime)
{
    (void)currentCommunicationPoint;
    (void)communicationStepSize;
    (void)noSetFMUStatePriorToCurrentPoint;
    (void)eventHandlingNeeded;
    (void)terminateSimulation;
    (void)earlyReturn;
    (void)lastSuccessfulTime;
    return not_supported(instance, "fmi3DoStep", "co-simulation");
}

FMI3_Export fmi3Status fmi3ActivateModelPartition(fmi3Instance instance, fmi3ValueReference clockReference,
                                                  fmi3Float64 activationTime)
{
    (void)clockReference;
    (void)activationTime;
    return not_supported(instance, "fmi3ActivateModelPartition", "Scheduled Execution");
}
