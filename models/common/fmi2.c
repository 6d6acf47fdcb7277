/* FMI 2.0 wrapper (co-simulation and model exchange) over the fmu-bridge model core. */
#include "fmi2Functions.h"
#include "fmu_core.h"

#include <stdlib.h>

typedef struct {
    FmuInstance core;   /* first member: an fmi2Component is also an FmuInstance* */
    fmi2CallbackFunctions callbacks;
} Fmi2Instance;

#define MODE(m) FMU_MODE_BIT(m)
#define INSTANCE_OR_ERROR(c)                      \
    FmuInstance* inst = (FmuInstance*)(c);         \
    if (inst == NULL) return fmi2Error

static void emit(FmuInstance* inst, FmuStatus status, const char* category, const char* message) {
    Fmi2Instance* w = (Fmi2Instance*)inst;
    if (w->callbacks.logger == NULL) return;
    w->callbacks.logger(w->callbacks.componentEnvironment, inst->name, (fmi2Status)status, category, message);
}

const char* fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

const char* fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    INSTANCE_OR_ERROR(c);
    return (fmi2Status)fmu_set_debug_logging(inst, "fmi2SetDebugLogging", loggingOn != fmi2False, nCategories,
                                             categories);
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions* functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn) {
    (void)fmuResourceLocation;
    (void)visible;
    Fmi2Instance* w = calloc(1, sizeof *w);
    if (w == NULL) return NULL;
    if (functions != NULL) w->callbacks = *functions;
    w->core.fmi_version = 2;
    w->core.emit = emit;
    FmuInterface requested = fmuType == fmi2CoSimulation ? FMU_CS : FMU_ME;
    if (fmu_setup(&w->core, "fmi2Instantiate", instanceName, fmuGUID, requested, loggingOn != fmi2False) != FMU_OK) {
        fmu_teardown(&w->core);
        free(w);
        return NULL;
    }
    return w;
}

void fmi2FreeInstance(fmi2Component c) {
    if (c == NULL) return;
    fmu_teardown((FmuInstance*)c);
    free(c);
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    (void)toleranceDefined;
    (void)tolerance;
    (void)stopTimeDefined;
    (void)stopTime;
    INSTANCE_OR_ERROR(c);
    if (!fmu_check_mode(inst, MODE(MODE_INSTANTIATED), "fmi2SetupExperiment")) return fmi2Error;
    inst->s.time = startTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    INSTANCE_OR_ERROR(c);
    return (fmi2Status)fmu_enter_initialization(inst, "fmi2EnterInitializationMode", inst->s.time);
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    INSTANCE_OR_ERROR(c);
    return (fmi2Status)fmu_exit_initialization(inst, "fmi2ExitInitializationMode");
}

fmi2Status fmi2Terminate(fmi2Component c) {
    INSTANCE_OR_ERROR(c);
    return (fmi2Status)fmu_terminate(inst, "fmi2Terminate");
}

fmi2Status fmi2Reset(fmi2Component c) {
    INSTANCE_OR_ERROR(c);
    return (fmi2Status)fmu_reset(inst, "fmi2Reset");
}

/* --- typed access -------------------------------------------------------------------------- */
#define REAL_TYPES FMU_TYPE_BIT(T_FLOAT64)
#define INTEGER_TYPES (FMU_TYPE_BIT(T_INT32) | FMU_TYPE_BIT(T_ENUMERATION))
#define BOOLEAN_TYPES FMU_TYPE_BIT(T_BOOLEAN)
#define STRING_TYPES FMU_TYPE_BIT(T_STRING)

#define DEFINE_GET(NAME, CTYPE, MASK, FROM)                                                        \
    fmi2Status NAME(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, CTYPE value[]) {   \
        INSTANCE_OR_ERROR(c);                                                                      \
        for (size_t k = 0; k < nvr; k++) {                                                         \
            FmuValue v;                                                                            \
            FmuStatus status = fmu_get(inst, #NAME, MASK, vr[k], &v);                              \
            if (status >= FMU_ERROR) return (fmi2Status)status;                                    \
            value[k] = FROM;                                                                       \
        }                                                                                          \
        return fmi2OK;                                                                             \
    }

#define DEFINE_SET(NAME, CTYPE, MASK, TO)                                                                \
    fmi2Status NAME(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const CTYPE value[]) {   \
        INSTANCE_OR_ERROR(c);                                                                            \
        FmuStatus worst = FMU_OK;                                                                        \
        for (size_t k = 0; k < nvr; k++) {                                                               \
            FmuValue v;                                                                                  \
            TO;                                                                                          \
            FmuStatus status = fmu_set(inst, #NAME, MASK, vr[k], &v);                                    \
            if (status >= FMU_ERROR) return (fmi2Status)status;                                          \
            if (status > worst) worst = status;                                                          \
        }                                                                                                \
        return (fmi2Status)worst;                                                                        \
    }

DEFINE_GET(fmi2GetReal, fmi2Real, REAL_TYPES, v.f)
DEFINE_GET(fmi2GetInteger, fmi2Integer, INTEGER_TYPES, (fmi2Integer)v.i)
DEFINE_GET(fmi2GetBoolean, fmi2Boolean, BOOLEAN_TYPES, v.b ? fmi2True : fmi2False)
DEFINE_GET(fmi2GetString, fmi2String, STRING_TYPES, v.s)
DEFINE_SET(fmi2SetReal, fmi2Real, REAL_TYPES, v.f = value[k])
DEFINE_SET(fmi2SetInteger, fmi2Integer, INTEGER_TYPES, v.i = value[k])
DEFINE_SET(fmi2SetBoolean, fmi2Boolean, BOOLEAN_TYPES, v.b = value[k] != fmi2False)
DEFINE_SET(fmi2SetString, fmi2String, STRING_TYPES, v.s = value[k])

/* --- FMU state ----------------------------------------------------------------------------- */
fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate* FMUstate) {
    INSTANCE_OR_ERROR(c);
    if (*FMUstate != NULL) return (fmi2Status)fmu_snapshot_update(inst, "fmi2GetFMUstate", *FMUstate);
    *FMUstate = fmu_snapshot_new(inst, "fmi2GetFMUstate");
    return *FMUstate != NULL ? fmi2OK : fmi2Error;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    INSTANCE_OR_ERROR(c);
    return (fmi2Status)fmu_snapshot_restore(inst, "fmi2SetFMUstate", FMUstate);
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate* FMUstate) {
    INSTANCE_OR_ERROR(c);
    fmu_snapshot_free(*FMUstate);
    *FMUstate = NULL;
    return fmi2OK;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t* size) {
    INSTANCE_OR_ERROR(c);
    return (fmi2Status)fmu_serialized_size(inst, "fmi2SerializedFMUstateSize", FMUstate, size);
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate, fmi2Byte serializedState[], size_t size) {
    INSTANCE_OR_ERROR(c);
    return (fmi2Status)fmu_serialize(inst, "fmi2SerializeFMUstate", FMUstate, (uint8_t*)serializedState, size);
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate* FMUstate) {
    INSTANCE_OR_ERROR(c);
    return (fmi2Status)fmu_deserialize(inst, "fmi2DeSerializeFMUstate", (const uint8_t*)serializedState, size,
                                       (FmuSnapshot**)FMUstate);
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[], size_t nUnknown,
                                        const fmi2ValueReference vKnown_ref[], size_t nKnown,
                                        const fmi2Real dvKnown[], fmi2Real dvUnknown[]) {
    (void)vUnknown_ref;
    (void)nUnknown;
    (void)vKnown_ref;
    (void)nKnown;
    (void)dvKnown;
    (void)dvUnknown;
    INSTANCE_OR_ERROR(c);
    return (fmi2Status)fmu_unsupported(inst, "fmi2GetDirectionalDerivative", "providesDirectionalDerivative is false");
}

/* --- model exchange ------------------------------------------------------------------------ */
fmi2Status fmi2EnterEventMode(fmi2Component c) {
    INSTANCE_OR_ERROR(c);
    return (fmi2Status)fmu_enter_event_mode(inst, "fmi2EnterEventMode");
}

fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo* eventInfo) {
    INSTANCE_OR_ERROR(c);
    FmuEventResult ev;
    FmuStatus status = fmu_event_update(inst, "fmi2NewDiscreteStates", &ev);
    eventInfo->newDiscreteStatesNeeded = ev.discrete_states_need_update;
    eventInfo->terminateSimulation = ev.terminate_simulation;
    eventInfo->nominalsOfContinuousStatesChanged = fmi2False;
    eventInfo->valuesOfContinuousStatesChanged = ev.values_of_continuous_states_changed;
    eventInfo->nextEventTimeDefined = ev.next_event_time_defined;
    eventInfo->nextEventTime = ev.next_event_time;
    return (fmi2Status)status;
}

fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) {
    INSTANCE_OR_ERROR(c);
    return (fmi2Status)fmu_enter_continuous_mode(inst, "fmi2EnterContinuousTimeMode");
}

fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi2Boolean* enterEventMode, fmi2Boolean* terminateSimulation) {
    (void)noSetFMUStatePriorToCurrentPoint;
    INSTANCE_OR_ERROR(c);
    if (!fmu_check_interface(inst, FMU_ME, "fmi2CompletedIntegratorStep")) return fmi2Error;
    *enterEventMode = fmi2False;
    *terminateSimulation = fmi2False;
    return fmi2OK;
}

fmi2Status fmi2SetTime(fmi2Component c, fmi2Real time) {
    INSTANCE_OR_ERROR(c);
    return (fmi2Status)fmu_set_time(inst, "fmi2SetTime", time);
}

fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t nx) {
    INSTANCE_OR_ERROR(c);
    return (fmi2Status)fmu_set_states(inst, "fmi2SetContinuousStates", x, nx);
}

fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real derivatives[], size_t nx) {
    INSTANCE_OR_ERROR(c);
    return (fmi2Status)fmu_get_derivatives(inst, "fmi2GetDerivatives", derivatives, nx);
}

fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real eventIndicators[], size_t ni) {
    INSTANCE_OR_ERROR(c);
    return (fmi2Status)fmu_get_event_indicators(inst, "fmi2GetEventIndicators", eventIndicators, ni);
}

fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t nx) {
    INSTANCE_OR_ERROR(c);
    return (fmi2Status)fmu_get_states(inst, "fmi2GetContinuousStates", x, nx);
}

fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x_nominal[], size_t nx) {
    INSTANCE_OR_ERROR(c);
    return (fmi2Status)fmu_get_nominals(inst, "fmi2GetNominalsOfContinuousStates", x_nominal, nx);
}

/* --- co-simulation ------------------------------------------------------------------------- */
fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    (void)vr;
    (void)nvr;
    (void)order;
    (void)value;
    INSTANCE_OR_ERROR(c);
    return (fmi2Status)fmu_unsupported(inst, "fmi2SetRealInputDerivatives", "canInterpolateInputs is false");
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[]) {
    (void)vr;
    (void)nvr;
    (void)order;
    (void)value;
    INSTANCE_OR_ERROR(c);
    return (fmi2Status)fmu_unsupported(inst, "fmi2GetRealOutputDerivatives", "maxOutputDerivativeOrder is 0");
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    (void)noSetFMUStatePriorToCurrentPoint;
    INSTANCE_OR_ERROR(c);
    FmuStatus status = fmu_do_step(inst, "fmi2DoStep", currentCommunicationPoint, communicationStepSize);
    /* FMI 2.0 signals a termination request as fmi2Discard + fmi2GetBooleanStatus(fmi2Terminated) */
    if (status <= FMU_WARNING && inst->s.terminate_requested) return fmi2Discard;
    return (fmi2Status)status;
}

fmi2Status fmi2CancelStep(fmi2Component c) {
    INSTANCE_OR_ERROR(c);
    return (fmi2Status)fmu_unsupported(inst, "fmi2CancelStep", "doStep never returns fmi2Pending");
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status* value) {
    (void)s;
    (void)value;
    INSTANCE_OR_ERROR(c);
    return fmi2Discard;   /* doStep is synchronous: there is no pending status to report */
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real* value) {
    INSTANCE_OR_ERROR(c);
    if (s != fmi2LastSuccessfulTime) return fmi2Discard;
    *value = inst->s.time;
    return fmi2OK;
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer* value) {
    (void)s;
    (void)value;
    INSTANCE_OR_ERROR(c);
    return fmi2Discard;
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean* value) {
    INSTANCE_OR_ERROR(c);
    if (s != fmi2Terminated) return fmi2Discard;
    *value = inst->s.terminate_requested ? fmi2True : fmi2False;
    return fmi2OK;
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String* value) {
    (void)s;
    (void)value;
    INSTANCE_OR_ERROR(c);
    return fmi2Discard;
}
