/* FMI 3.0 wrapper (co-simulation and model exchange) over the fmu-bridge model core.
 * Arrays (Float64) and Binary variables are read and written; clocks are declared with a constant
 * interval but never tick (no event mode in co-simulation). Configuration mode and scheduled execution
 * are not used by our models; their functions exist (importers bind every symbol) and report an error. */
#include "fmi3Functions.h"
#include "fmu_core.h"

#include <stdlib.h>

typedef struct {
    FmuInstance core;   /* first member: an fmi3Instance is also an FmuInstance* */
    fmi3InstanceEnvironment environment;
    fmi3LogMessageCallback log_message;
} Fmi3Instance;

#define INSTANCE_OR_ERROR(c)                      \
    FmuInstance* inst = (FmuInstance*)(c);         \
    if (inst == NULL) return fmi3Error
#define UNUSED(x) (void)(x)

static void emit(FmuInstance* inst, FmuStatus status, const char* category, const char* message) {
    Fmi3Instance* w = (Fmi3Instance*)inst;
    if (w->log_message != NULL) w->log_message(w->environment, (fmi3Status)status, category, message);
}

static Fmi3Instance* instantiate(const char* fn, fmi3String name, fmi3String token, FmuInterface requested,
                                 fmi3Boolean loggingOn, fmi3InstanceEnvironment env, fmi3LogMessageCallback log) {
    Fmi3Instance* w = calloc(1, sizeof *w);
    if (w == NULL) return NULL;
    w->environment = env;
    w->log_message = log;
    w->core.fmi_version = 3;
    w->core.emit = emit;
    if (fmu_setup(&w->core, fn, name, token, requested, loggingOn) != FMU_OK) {
        fmu_teardown(&w->core);
        free(w);
        return NULL;
    }
    return w;
}

const char* fmi3GetVersion(void) { return fmi3Version; }

fmi3Status fmi3SetDebugLogging(fmi3Instance instance, fmi3Boolean loggingOn, size_t nCategories,
                               const fmi3String categories[]) {
    INSTANCE_OR_ERROR(instance);
    return (fmi3Status)fmu_set_debug_logging(inst, "fmi3SetDebugLogging", loggingOn, nCategories, categories);
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage) {
    UNUSED(resourcePath);
    UNUSED(visible);
    return instantiate("fmi3InstantiateModelExchange", instanceName, instantiationToken, FMU_ME, loggingOn,
                       instanceEnvironment, logMessage);
}

fmi3Instance fmi3InstantiateCoSimulation(fmi3String instanceName, fmi3String instantiationToken,
                                         fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                         fmi3Boolean eventModeUsed, fmi3Boolean earlyReturnAllowed,
                                         const fmi3ValueReference requiredIntermediateVariables[],
                                         size_t nRequiredIntermediateVariables,
                                         fmi3InstanceEnvironment instanceEnvironment,
                                         fmi3LogMessageCallback logMessage,
                                         fmi3IntermediateUpdateCallback intermediateUpdate) {
    UNUSED(resourcePath);
    UNUSED(visible);
    UNUSED(earlyReturnAllowed);
    UNUSED(requiredIntermediateVariables);
    UNUSED(nRequiredIntermediateVariables);
    UNUSED(intermediateUpdate);
    Fmi3Instance* w = instantiate("fmi3InstantiateCoSimulation", instanceName, instantiationToken, FMU_CS,
                                  loggingOn, instanceEnvironment, logMessage);
    if (w != NULL && eventModeUsed) {
        fmu_unsupported(&w->core, "fmi3InstantiateCoSimulation with eventModeUsed", "hasEventMode is false");
        fmu_teardown(&w->core);
        free(w);
        return NULL;
    }
    return w;
}

fmi3Instance fmi3InstantiateScheduledExecution(fmi3String instanceName, fmi3String instantiationToken,
                                               fmi3String resourcePath, fmi3Boolean visible,
                                               fmi3Boolean loggingOn, fmi3InstanceEnvironment instanceEnvironment,
                                               fmi3LogMessageCallback logMessage, fmi3ClockUpdateCallback clockUpdate,
                                               fmi3LockPreemptionCallback lockPreemption,
                                               fmi3UnlockPreemptionCallback unlockPreemption) {
    UNUSED(instantiationToken);
    UNUSED(resourcePath);
    UNUSED(visible);
    UNUSED(loggingOn);
    UNUSED(clockUpdate);
    UNUSED(lockPreemption);
    UNUSED(unlockPreemption);
    if (logMessage != NULL) {
        logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                   "fmi3InstantiateScheduledExecution is not supported: the model has no ScheduledExecution "
                   "interface");
    }
    UNUSED(instanceName);
    return NULL;
}

void fmi3FreeInstance(fmi3Instance instance) {
    if (instance == NULL) return;
    fmu_teardown((FmuInstance*)instance);
    free(instance);
}

fmi3Status fmi3EnterInitializationMode(fmi3Instance instance, fmi3Boolean toleranceDefined, fmi3Float64 tolerance,
                                       fmi3Float64 startTime, fmi3Boolean stopTimeDefined, fmi3Float64 stopTime) {
    UNUSED(toleranceDefined);
    UNUSED(tolerance);
    UNUSED(stopTimeDefined);
    UNUSED(stopTime);
    INSTANCE_OR_ERROR(instance);
    return (fmi3Status)fmu_enter_initialization(inst, "fmi3EnterInitializationMode", startTime);
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance instance) {
    INSTANCE_OR_ERROR(instance);
    return (fmi3Status)fmu_exit_initialization(inst, "fmi3ExitInitializationMode");
}

fmi3Status fmi3EnterEventMode(fmi3Instance instance) {
    INSTANCE_OR_ERROR(instance);
    return (fmi3Status)fmu_enter_event_mode(inst, "fmi3EnterEventMode");
}

fmi3Status fmi3Terminate(fmi3Instance instance) {
    INSTANCE_OR_ERROR(instance);
    return (fmi3Status)fmu_terminate(inst, "fmi3Terminate");
}

fmi3Status fmi3Reset(fmi3Instance instance) {
    INSTANCE_OR_ERROR(instance);
    return (fmi3Status)fmu_reset(inst, "fmi3Reset");
}

/* --- typed access -------------------------------------------------------------------------- */
/* FMI 3.0 passes arrays flattened: nValues is the sum of the element counts of the value references. */
static bool check_value_count(FmuInstance* inst, const char* fn, const fmi3ValueReference vr[], size_t nvr,
                              size_t nValues) {
    size_t expected = 0;
    for (size_t k = 0; k < nvr; k++) expected += fmu_value_count(vr[k]);
    return fmu_check_count(inst, fn, nValues, expected, "values (the element counts of the value references)");
}

#define DEFINE_GET(NAME, CTYPE, MASK, FROM)                                                           \
    fmi3Status NAME(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, CTYPE values[], \
                    size_t nValues) {                                                                 \
        INSTANCE_OR_ERROR(instance);                                                                  \
        if (!check_value_count(inst, #NAME, vr, nvr, nValues)) return fmi3Error;                     \
        size_t n = 0;                                                                                 \
        for (size_t k = 0; k < nvr; k++) {                                                            \
            for (size_t e = 0; e < fmu_value_count(vr[k]); e++, n++) {                                \
                FmuValue v;                                                                           \
                FmuStatus status = fmu_get_element(inst, #NAME, MASK, vr[k], e, &v);                  \
                if (status >= FMU_ERROR) return (fmi3Status)status;                                   \
                values[n] = FROM;                                                                     \
            }                                                                                         \
        }                                                                                             \
        return fmi3OK;                                                                                \
    }

#define DEFINE_SET(NAME, CTYPE, MASK, TO)                                                                   \
    fmi3Status NAME(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, const CTYPE values[], \
                    size_t nValues) {                                                                       \
        INSTANCE_OR_ERROR(instance);                                                                        \
        if (!check_value_count(inst, #NAME, vr, nvr, nValues)) return fmi3Error;                           \
        FmuStatus worst = FMU_OK;                                                                           \
        size_t n = 0;                                                                                       \
        for (size_t k = 0; k < nvr; k++) {                                                                  \
            for (size_t e = 0; e < fmu_value_count(vr[k]); e++, n++) {                                      \
                FmuValue v;                                                                                 \
                TO;                                                                                         \
                FmuStatus status = fmu_set_element(inst, #NAME, MASK, vr[k], e, &v);                        \
                if (status >= FMU_ERROR) return (fmi3Status)status;                                         \
                if (status > worst) worst = status;                                                         \
            }                                                                                               \
        }                                                                                                   \
        return (fmi3Status)worst;                                                                           \
    }

#define BIT(t) FMU_TYPE_BIT(t)
DEFINE_GET(fmi3GetFloat32, fmi3Float32, BIT(T_FLOAT32), (fmi3Float32)v.f)
DEFINE_GET(fmi3GetFloat64, fmi3Float64, BIT(T_FLOAT64), v.f)
DEFINE_GET(fmi3GetInt8, fmi3Int8, BIT(T_INT8), (fmi3Int8)v.i)
DEFINE_GET(fmi3GetUInt8, fmi3UInt8, BIT(T_UINT8), (fmi3UInt8)v.u)
DEFINE_GET(fmi3GetInt16, fmi3Int16, BIT(T_INT16), (fmi3Int16)v.i)
DEFINE_GET(fmi3GetUInt16, fmi3UInt16, BIT(T_UINT16), (fmi3UInt16)v.u)
DEFINE_GET(fmi3GetInt32, fmi3Int32, BIT(T_INT32), (fmi3Int32)v.i)
DEFINE_GET(fmi3GetUInt32, fmi3UInt32, BIT(T_UINT32), (fmi3UInt32)v.u)
DEFINE_GET(fmi3GetInt64, fmi3Int64, BIT(T_INT64) | BIT(T_ENUMERATION), v.i)
DEFINE_GET(fmi3GetUInt64, fmi3UInt64, BIT(T_UINT64), v.u)
DEFINE_GET(fmi3GetBoolean, fmi3Boolean, BIT(T_BOOLEAN), v.b)
DEFINE_GET(fmi3GetString, fmi3String, BIT(T_STRING), v.s)
DEFINE_SET(fmi3SetFloat32, fmi3Float32, BIT(T_FLOAT32), v.f = values[n])
DEFINE_SET(fmi3SetFloat64, fmi3Float64, BIT(T_FLOAT64), v.f = values[n])
DEFINE_SET(fmi3SetInt8, fmi3Int8, BIT(T_INT8), v.i = values[n])
DEFINE_SET(fmi3SetUInt8, fmi3UInt8, BIT(T_UINT8), v.u = values[n])
DEFINE_SET(fmi3SetInt16, fmi3Int16, BIT(T_INT16), v.i = values[n])
DEFINE_SET(fmi3SetUInt16, fmi3UInt16, BIT(T_UINT16), v.u = values[n])
DEFINE_SET(fmi3SetInt32, fmi3Int32, BIT(T_INT32), v.i = values[n])
DEFINE_SET(fmi3SetUInt32, fmi3UInt32, BIT(T_UINT32), v.u = values[n])
DEFINE_SET(fmi3SetInt64, fmi3Int64, BIT(T_INT64) | BIT(T_ENUMERATION), v.i = values[n])
DEFINE_SET(fmi3SetUInt64, fmi3UInt64, BIT(T_UINT64), v.u = values[n])
DEFINE_SET(fmi3SetBoolean, fmi3Boolean, BIT(T_BOOLEAN), v.b = values[n])
DEFINE_SET(fmi3SetString, fmi3String, BIT(T_STRING), v.s = values[n])

/* Binary values point into memory the instance owns; they stay valid until the next call. */
fmi3Status fmi3GetBinary(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, size_t valueSizes[],
                         fmi3Binary values[], size_t nValues) {
    INSTANCE_OR_ERROR(instance);
    if (!check_value_count(inst, "fmi3GetBinary", vr, nvr, nValues)) return fmi3Error;
    for (size_t k = 0; k < nvr; k++) {
        FmuValue v;
        FmuStatus status = fmu_get(inst, "fmi3GetBinary", BIT(T_BINARY), vr[k], &v);
        if (status >= FMU_ERROR) return (fmi3Status)status;
        values[k] = v.bin.data;
        valueSizes[k] = v.bin.size;
    }
    return fmi3OK;
}

fmi3Status fmi3SetBinary(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                         const size_t valueSizes[], const fmi3Binary values[], size_t nValues) {
    INSTANCE_OR_ERROR(instance);
    if (!check_value_count(inst, "fmi3SetBinary", vr, nvr, nValues)) return fmi3Error;
    FmuStatus worst = FMU_OK;
    for (size_t k = 0; k < nvr; k++) {
        FmuValue v;
        v.bin.data = values[k];
        v.bin.size = valueSizes[k];
        FmuStatus status = fmu_set(inst, "fmi3SetBinary", BIT(T_BINARY), vr[k], &v);
        if (status >= FMU_ERROR) return (fmi3Status)status;
        if (status > worst) worst = status;
    }
    return (fmi3Status)worst;
}

/* Clocks are declared (their kind and interval) but only tick in event mode, which these
 * co-simulation models do not offer (hasEventMode is false): a clock reads inactive, and
 * activating one is refused. */
fmi3Status fmi3GetClock(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, fmi3Clock values[]) {
    INSTANCE_OR_ERROR(instance);
    for (size_t k = 0; k < nvr; k++) {
        FmuValue v;
        FmuStatus status = fmu_get(inst, "fmi3GetClock", BIT(T_CLOCK), vr[k], &v);
        if (status >= FMU_ERROR) return (fmi3Status)status;
        values[k] = v.b;
    }
    return fmi3OK;
}

fmi3Status fmi3SetClock(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                        const fmi3Clock values[]) {
    UNUSED(vr);
    UNUSED(values);
    INSTANCE_OR_ERROR(instance);
    if (nvr == 0) return fmi3OK;
    return (fmi3Status)fmu_unsupported(inst, "fmi3SetClock", "clocks tick only in event mode and hasEventMode is "
                                       "false");
}

/* Any other value reference passed to a clock function is wrong. */
static fmi3Status no_such_type(fmi3Instance instance, const char* fn, const fmi3ValueReference vr[], size_t nvr,
                               const char* type) {
    INSTANCE_OR_ERROR(instance);
    if (nvr == 0) return fmi3OK;
    fmu_log_error(inst, "%s: value reference %u is not a %s variable with that property; see "
                  "modelDescription.xml of %s", fn, vr[0], type, MODEL_NAME);
    return fmi3Error;
}

/* --- dependencies, FMU state, derivatives -------------------------------------------------- */
fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance instance, fmi3ValueReference valueReference,
                                               size_t* nDependencies) {
    UNUSED(valueReference);
    UNUSED(nDependencies);
    INSTANCE_OR_ERROR(instance);
    return (fmi3Status)fmu_unsupported(inst, "fmi3GetNumberOfVariableDependencies",
                                       "providesPerElementDependencies is false");
}

fmi3Status fmi3GetVariableDependencies(fmi3Instance instance, fmi3ValueReference dependent,
                                       size_t elementIndicesOfDependent[], fmi3ValueReference independents[],
                                       size_t elementIndicesOfIndependents[], fmi3DependencyKind dependencyKinds[],
                                       size_t nDependencies) {
    UNUSED(dependent);
    UNUSED(elementIndicesOfDependent);
    UNUSED(independents);
    UNUSED(elementIndicesOfIndependents);
    UNUSED(dependencyKinds);
    UNUSED(nDependencies);
    INSTANCE_OR_ERROR(instance);
    return (fmi3Status)fmu_unsupported(inst, "fmi3GetVariableDependencies", "providesPerElementDependencies is false");
}

fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState* FMUState) {
    INSTANCE_OR_ERROR(instance);
    if (*FMUState != NULL) return (fmi3Status)fmu_snapshot_update(inst, "fmi3GetFMUState", *FMUState);
    *FMUState = fmu_snapshot_new(inst, "fmi3GetFMUState");
    return *FMUState != NULL ? fmi3OK : fmi3Error;
}

fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState FMUState) {
    INSTANCE_OR_ERROR(instance);
    return (fmi3Status)fmu_snapshot_restore(inst, "fmi3SetFMUState", FMUState);
}

fmi3Status fmi3FreeFMUState(fmi3Instance instance, fmi3FMUState* FMUState) {
    INSTANCE_OR_ERROR(instance);
    fmu_snapshot_free(*FMUState);
    *FMUState = NULL;
    return fmi3OK;
}

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance instance, fmi3FMUState FMUState, size_t* size) {
    INSTANCE_OR_ERROR(instance);
    return (fmi3Status)fmu_serialized_size(inst, "fmi3SerializedFMUStateSize", FMUState, size);
}

fmi3Status fmi3SerializeFMUState(fmi3Instance instance, fmi3FMUState FMUState, fmi3Byte serializedState[],
                                 size_t size) {
    INSTANCE_OR_ERROR(instance);
    return (fmi3Status)fmu_serialize(inst, "fmi3SerializeFMUState", FMUState, serializedState, size);
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance instance, const fmi3Byte serializedState[], size_t size,
                                   fmi3FMUState* FMUState) {
    INSTANCE_OR_ERROR(instance);
    return (fmi3Status)fmu_deserialize(inst, "fmi3DeserializeFMUState", serializedState, size,
                                       (FmuSnapshot**)FMUState);
}

fmi3Status fmi3GetDirectionalDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[],
                                        size_t nUnknowns, const fmi3ValueReference knowns[], size_t nKnowns,
                                        const fmi3Float64 seed[], size_t nSeed, fmi3Float64 sensitivity[],
                                        size_t nSensitivity) {
    UNUSED(unknowns);
    UNUSED(nUnknowns);
    UNUSED(knowns);
    UNUSED(nKnowns);
    UNUSED(seed);
    UNUSED(nSeed);
    UNUSED(sensitivity);
    UNUSED(nSensitivity);
    INSTANCE_OR_ERROR(instance);
    return (fmi3Status)fmu_unsupported(inst, "fmi3GetDirectionalDerivative", "providesDirectionalDerivatives is false");
}

fmi3Status fmi3GetAdjointDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[], size_t nUnknowns,
                                    const fmi3ValueReference knowns[], size_t nKnowns, const fmi3Float64 seed[],
                                    size_t nSeed, fmi3Float64 sensitivity[], size_t nSensitivity) {
    UNUSED(unknowns);
    UNUSED(nUnknowns);
    UNUSED(knowns);
    UNUSED(nKnowns);
    UNUSED(seed);
    UNUSED(nSeed);
    UNUSED(sensitivity);
    UNUSED(nSensitivity);
    INSTANCE_OR_ERROR(instance);
    return (fmi3Status)fmu_unsupported(inst, "fmi3GetAdjointDerivative", "providesAdjointDerivatives is false");
}

/* --- configuration mode and clocks (not used by these models) ------------------------------ */
fmi3Status fmi3EnterConfigurationMode(fmi3Instance instance) {
    INSTANCE_OR_ERROR(instance);
    return (fmi3Status)fmu_unsupported(inst, "fmi3EnterConfigurationMode", "the model has no structural parameters");
}

fmi3Status fmi3ExitConfigurationMode(fmi3Instance instance) {
    INSTANCE_OR_ERROR(instance);
    return (fmi3Status)fmu_unsupported(inst, "fmi3ExitConfigurationMode", "the model has no structural parameters");
}

fmi3Status fmi3GetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                  fmi3Float64 intervals[], fmi3IntervalQualifier qualifiers[]) {
    INSTANCE_OR_ERROR(instance);
    for (size_t k = 0; k < nvr; k++) {
        FmuValue v;
        if (fmu_get(inst, "fmi3GetIntervalDecimal", BIT(T_CLOCK), vr[k], &v) >= FMU_ERROR) return fmi3Error;
        intervals[k] = MODEL_VARIABLES[vr[k]].interval; /* constant intervals, declared in the XML */
        qualifiers[k] = fmi3IntervalUnchanged;
    }
    return fmi3OK;
}

fmi3Status fmi3GetIntervalFraction(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                   fmi3UInt64 counters[], fmi3UInt64 resolutions[],
                                   fmi3IntervalQualifier qualifiers[]) {
    UNUSED(counters);
    UNUSED(resolutions);
    UNUSED(qualifiers);
    return no_such_type(instance, "fmi3GetIntervalFraction", vr, nvr, "Clock");
}

fmi3Status fmi3GetShiftDecimal(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                               fmi3Float64 shifts[]) {
    UNUSED(shifts);
    return no_such_type(instance, "fmi3GetShiftDecimal", vr, nvr, "Clock");
}

fmi3Status fmi3GetShiftFraction(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                fmi3UInt64 counters[], fmi3UInt64 resolutions[]) {
    UNUSED(counters);
    UNUSED(resolutions);
    return no_such_type(instance, "fmi3GetShiftFraction", vr, nvr, "Clock");
}

fmi3Status fmi3SetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                  const fmi3Float64 intervals[]) {
    UNUSED(intervals);
    return no_such_type(instance, "fmi3SetIntervalDecimal", vr, nvr, "Clock");
}

fmi3Status fmi3SetIntervalFraction(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                   const fmi3UInt64 counters[], const fmi3UInt64 resolutions[]) {
    UNUSED(counters);
    UNUSED(resolutions);
    return no_such_type(instance, "fmi3SetIntervalFraction", vr, nvr, "Clock");
}

fmi3Status fmi3SetShiftDecimal(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                               const fmi3Float64 shifts[]) {
    UNUSED(shifts);
    return no_such_type(instance, "fmi3SetShiftDecimal", vr, nvr, "Clock");
}

fmi3Status fmi3SetShiftFraction(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                const fmi3UInt64 counters[], const fmi3UInt64 resolutions[]) {
    UNUSED(counters);
    UNUSED(resolutions);
    return no_such_type(instance, "fmi3SetShiftFraction", vr, nvr, "Clock");
}

fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance instance) {
    INSTANCE_OR_ERROR(instance);
    return (fmi3Status)fmu_unsupported(inst, "fmi3EvaluateDiscreteStates", "providesEvaluateDiscreteStates is false");
}

fmi3Status fmi3UpdateDiscreteStates(fmi3Instance instance, fmi3Boolean* discreteStatesNeedUpdate,
                                    fmi3Boolean* terminateSimulation, fmi3Boolean* nominalsOfContinuousStatesChanged,
                                    fmi3Boolean* valuesOfContinuousStatesChanged, fmi3Boolean* nextEventTimeDefined,
                                    fmi3Float64* nextEventTime) {
    INSTANCE_OR_ERROR(instance);
    FmuEventResult ev;
    FmuStatus status = fmu_event_update(inst, "fmi3UpdateDiscreteStates", &ev);
    *discreteStatesNeedUpdate = ev.discrete_states_need_update;
    *terminateSimulation = ev.terminate_simulation;
    *nominalsOfContinuousStatesChanged = false;
    *valuesOfContinuousStatesChanged = ev.values_of_continuous_states_changed;
    *nextEventTimeDefined = ev.next_event_time_defined;
    *nextEventTime = ev.next_event_time;
    return (fmi3Status)status;
}

/* --- model exchange ------------------------------------------------------------------------ */
fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance instance) {
    INSTANCE_OR_ERROR(instance);
    return (fmi3Status)fmu_enter_continuous_mode(inst, "fmi3EnterContinuousTimeMode");
}

fmi3Status fmi3CompletedIntegratorStep(fmi3Instance instance, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean* enterEventMode, fmi3Boolean* terminateSimulation) {
    UNUSED(noSetFMUStatePriorToCurrentPoint);
    INSTANCE_OR_ERROR(instance);
    if (!fmu_check_interface(inst, FMU_ME, "fmi3CompletedIntegratorStep")) return fmi3Error;
    *enterEventMode = false;
    *terminateSimulation = false;
    return fmi3OK;
}

fmi3Status fmi3SetTime(fmi3Instance instance, fmi3Float64 time) {
    INSTANCE_OR_ERROR(instance);
    return (fmi3Status)fmu_set_time(inst, "fmi3SetTime", time);
}

fmi3Status fmi3SetContinuousStates(fmi3Instance instance, const fmi3Float64 continuousStates[],
                                   size_t nContinuousStates) {
    INSTANCE_OR_ERROR(instance);
    return (fmi3Status)fmu_set_states(inst, "fmi3SetContinuousStates", continuousStates, nContinuousStates);
}

fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance instance, fmi3Float64 derivatives[],
                                             size_t nContinuousStates) {
    INSTANCE_OR_ERROR(instance);
    return (fmi3Status)fmu_get_derivatives(inst, "fmi3GetContinuousStateDerivatives", derivatives,
                                           nContinuousStates);
}

fmi3Status fmi3GetEventIndicators(fmi3Instance instance, fmi3Float64 eventIndicators[], size_t nEventIndicators) {
    INSTANCE_OR_ERROR(instance);
    return (fmi3Status)fmu_get_event_indicators(inst, "fmi3GetEventIndicators", eventIndicators, nEventIndicators);
}

fmi3Status fmi3GetContinuousStates(fmi3Instance instance, fmi3Float64 continuousStates[],
                                   size_t nContinuousStates) {
    INSTANCE_OR_ERROR(instance);
    return (fmi3Status)fmu_get_states(inst, "fmi3GetContinuousStates", continuousStates, nContinuousStates);
}

fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance instance, fmi3Float64 nominals[],
                                             size_t nContinuousStates) {
    INSTANCE_OR_ERROR(instance);
    return (fmi3Status)fmu_get_nominals(inst, "fmi3GetNominalsOfContinuousStates", nominals, nContinuousStates);
}

fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance instance, size_t* nEventIndicators) {
    INSTANCE_OR_ERROR(instance);
    *nEventIndicators = MODEL_NZ;
    return fmi3OK;
}

fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance instance, size_t* nContinuousStates) {
    INSTANCE_OR_ERROR(instance);
    *nContinuousStates = MODEL_NX;
    return fmi3OK;
}

/* --- co-simulation ------------------------------------------------------------------------- */
fmi3Status fmi3EnterStepMode(fmi3Instance instance) {
    INSTANCE_OR_ERROR(instance);
    return (fmi3Status)fmu_unsupported(inst, "fmi3EnterStepMode", "hasEventMode is false");
}

fmi3Status fmi3GetOutputDerivatives(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                    const fmi3Int32 orders[], fmi3Float64 values[], size_t nValues) {
    UNUSED(vr);
    UNUSED(nvr);
    UNUSED(orders);
    UNUSED(values);
    UNUSED(nValues);
    INSTANCE_OR_ERROR(instance);
    return (fmi3Status)fmu_unsupported(inst, "fmi3GetOutputDerivatives", "maxOutputDerivativeOrder is 0");
}

fmi3Status fmi3DoStep(fmi3Instance instance, fmi3Float64 currentCommunicationPoint,
                      fmi3Float64 communicationStepSize, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                      fmi3Boolean* eventHandlingNeeded, fmi3Boolean* terminateSimulation, fmi3Boolean* earlyReturn,
                      fmi3Float64* lastSuccessfulTime) {
    UNUSED(noSetFMUStatePriorToCurrentPoint);
    INSTANCE_OR_ERROR(instance);
    FmuStatus status = fmu_do_step(inst, "fmi3DoStep", currentCommunicationPoint, communicationStepSize);
    *eventHandlingNeeded = false;
    *terminateSimulation = inst->s.terminate_requested;
    *earlyReturn = false;
    *lastSuccessfulTime = inst->s.time;
    return (fmi3Status)status;
}

fmi3Status fmi3ActivateModelPartition(fmi3Instance instance, fmi3ValueReference clockReference,
                                      fmi3Float64 activationTime) {
    UNUSED(clockReference);
    UNUSED(activationTime);
    INSTANCE_OR_ERROR(instance);
    return (fmi3Status)fmu_unsupported(inst, "fmi3ActivateModelPartition", "no ScheduledExecution interface");
}
