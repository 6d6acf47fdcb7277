/* FMI 1.0 model-exchange wrapper over the fmu-bridge model core.
 * FMI 1.0 prefixes every function with the model identifier (<MODEL_IDENTIFIER>_fmiEventUpdate etc.)
 * and has no modes: fmiInitialize runs the first event iteration, fmiEventUpdate one iteration at an
 * event. The core's event and continuous-time modes are entered and left inside these two calls, so
 * inputs of every variability may be set between them, as FMI 1.0 allows. */
#include <stddef.h>  /* fmi1Functions.h uses size_t without including it */

#include "fmi1Functions.h"
#include "fmu_core.h"

#include <stdlib.h>

#define FMI1_PASTE2(a, b) a##_##b
#define FMI1_PASTE(a, b) FMI1_PASTE2(a, b)
#define FMI1(name) FMI1_PASTE(MODEL_IDENTIFIER, name)
#define FMI1_EXPORT __attribute__((visibility("default")))
#define INSTANCE_OR_ERROR(c)                      \
    FmuInstance* inst = (FmuInstance*)(c);         \
    if (inst == NULL) return fmi1Error

FMI1_EXPORT fmi1GetModelTypesPlatformTYPE FMI1(fmiGetModelTypesPlatform);
FMI1_EXPORT fmi1GetVersionTYPE FMI1(fmiGetVersion);
FMI1_EXPORT fmi1InstantiateModelTYPE FMI1(fmiInstantiateModel);
FMI1_EXPORT fmi1FreeModelInstanceTYPE FMI1(fmiFreeModelInstance);
FMI1_EXPORT fmi1SetDebugLoggingTYPE FMI1(fmiSetDebugLogging);
FMI1_EXPORT fmi1SetTimeTYPE FMI1(fmiSetTime);
FMI1_EXPORT fmi1SetContinuousStatesTYPE FMI1(fmiSetContinuousStates);
FMI1_EXPORT fmi1CompletedIntegratorStepTYPE FMI1(fmiCompletedIntegratorStep);
FMI1_EXPORT fmi1SetRealTYPE FMI1(fmiSetReal);
FMI1_EXPORT fmi1SetIntegerTYPE FMI1(fmiSetInteger);
FMI1_EXPORT fmi1SetBooleanTYPE FMI1(fmiSetBoolean);
FMI1_EXPORT fmi1SetStringTYPE FMI1(fmiSetString);
FMI1_EXPORT fmi1InitializeTYPE FMI1(fmiInitialize);
FMI1_EXPORT fmi1GetDerivativesTYPE FMI1(fmiGetDerivatives);
FMI1_EXPORT fmi1GetEventIndicatorsTYPE FMI1(fmiGetEventIndicators);
FMI1_EXPORT fmi1GetRealTYPE FMI1(fmiGetReal);
FMI1_EXPORT fmi1GetIntegerTYPE FMI1(fmiGetInteger);
FMI1_EXPORT fmi1GetBooleanTYPE FMI1(fmiGetBoolean);
FMI1_EXPORT fmi1GetStringTYPE FMI1(fmiGetString);
FMI1_EXPORT fmi1EventUpdateTYPE FMI1(fmiEventUpdate);
FMI1_EXPORT fmi1GetContinuousStatesTYPE FMI1(fmiGetContinuousStates);
FMI1_EXPORT fmi1GetNominalContinuousStatesTYPE FMI1(fmiGetNominalContinuousStates);
FMI1_EXPORT fmi1GetStateValueReferencesTYPE FMI1(fmiGetStateValueReferences);
FMI1_EXPORT fmi1TerminateTYPE FMI1(fmiTerminate);

typedef struct {
    FmuInstance core;   /* first member: an fmiComponent is also an FmuInstance* */
    fmi1CallbackFunctions callbacks;
} Fmi1Instance;

static void emit(FmuInstance* inst, FmuStatus status, const char* category, const char* message) {
    Fmi1Instance* w = (Fmi1Instance*)inst;
    if (w->callbacks.logger != NULL) w->callbacks.logger(inst, inst->name, (fmi1Status)status, category, message);
}

const char* FMI1(fmiGetModelTypesPlatform)(void) { return "standard32"; }

const char* FMI1(fmiGetVersion)(void) { return "1.0"; }

fmi1Status FMI1(fmiSetDebugLogging)(fmi1Component c, fmi1Boolean loggingOn) {
    INSTANCE_OR_ERROR(c);
    return (fmi1Status)fmu_set_debug_logging(inst, "fmiSetDebugLogging", loggingOn != fmi1False, 0, NULL);
}

#define REAL_TYPES FMU_TYPE_BIT(T_FLOAT64)
#define INTEGER_TYPES (FMU_TYPE_BIT(T_INT32) | FMU_TYPE_BIT(T_ENUMERATION))
#define BOOLEAN_TYPES FMU_TYPE_BIT(T_BOOLEAN)
#define STRING_TYPES FMU_TYPE_BIT(T_STRING)

#define DEFINE_GET(NAME, CTYPE, MASK, FROM)                                                           \
    fmi1Status FMI1(NAME)(fmi1Component c, const fmi1ValueReference vr[], size_t nvr, CTYPE value[]) { \
        INSTANCE_OR_ERROR(c);                                                                         \
        for (size_t k = 0; k < nvr; k++) {                                                            \
            FmuValue v;                                                                               \
            FmuStatus status = fmu_get(inst, #NAME, MASK, vr[k], &v);                                 \
            if (status >= FMU_ERROR) return (fmi1Status)status;                                       \
            value[k] = FROM;                                                                          \
        }                                                                                             \
        return fmi1OK;                                                                                \
    }

#define DEFINE_SET(NAME, CTYPE, MASK, TO)                                                                   \
    fmi1Status FMI1(NAME)(fmi1Component c, const fmi1ValueReference vr[], size_t nvr, const CTYPE value[]) { \
        INSTANCE_OR_ERROR(c);                                                                               \
        FmuStatus worst = FMU_OK;                                                                           \
        for (size_t k = 0; k < nvr; k++) {                                                                  \
            FmuValue v;                                                                                     \
            TO;                                                                                             \
            FmuStatus status = fmu_set(inst, #NAME, MASK, vr[k], &v);                                       \
            if (status >= FMU_ERROR) return (fmi1Status)status;                                             \
            if (status > worst) worst = status;                                                             \
        }                                                                                                   \
        return (fmi1Status)worst;                                                                           \
    }

DEFINE_GET(fmiGetReal, fmi1Real, REAL_TYPES, v.f)
DEFINE_GET(fmiGetInteger, fmi1Integer, INTEGER_TYPES, (fmi1Integer)v.i)
DEFINE_GET(fmiGetBoolean, fmi1Boolean, BOOLEAN_TYPES, v.b ? fmi1True : fmi1False)
DEFINE_GET(fmiGetString, fmi1String, STRING_TYPES, v.s)
DEFINE_SET(fmiSetReal, fmi1Real, REAL_TYPES, v.f = value[k])
DEFINE_SET(fmiSetInteger, fmi1Integer, INTEGER_TYPES, v.i = value[k])
DEFINE_SET(fmiSetBoolean, fmi1Boolean, BOOLEAN_TYPES, v.b = value[k] != fmi1False)
DEFINE_SET(fmiSetString, fmi1String, STRING_TYPES, v.s = value[k])

fmi1Component FMI1(fmiInstantiateModel)(fmi1String instanceName, fmi1String GUID, fmi1CallbackFunctions functions,
                                        fmi1Boolean loggingOn) {
    Fmi1Instance* w = calloc(1, sizeof *w);
    if (w == NULL) return NULL;
    w->callbacks = functions;
    w->core.fmi_version = 1;
    w->core.emit = emit;
    if (fmu_setup(&w->core, "fmiInstantiateModel", instanceName, GUID, FMU_ME, loggingOn != fmi1False) != FMU_OK) {
        fmu_teardown(&w->core);
        free(w);
        return NULL;
    }
    return w;
}

void FMI1(fmiFreeModelInstance)(fmi1Component c) {
    if (c == NULL) return;
    fmu_teardown((FmuInstance*)c);
    free(c);
}

fmi1Status FMI1(fmiSetTime)(fmi1Component c, fmi1Real time) {
    INSTANCE_OR_ERROR(c);
    if (inst->s.mode == MODE_INSTANTIATED) {  /* the start time, given before fmiInitialize */
        inst->s.time = time;
        return fmi1OK;
    }
    return (fmi1Status)fmu_set_time(inst, "fmiSetTime", time);
}

fmi1Status FMI1(fmiSetContinuousStates)(fmi1Component c, const fmi1Real x[], size_t nx) {
    INSTANCE_OR_ERROR(c);
    return (fmi1Status)fmu_set_states(inst, "fmiSetContinuousStates", x, nx);
}

fmi1Status FMI1(fmiCompletedIntegratorStep)(fmi1Component c, fmi1Boolean* callEventUpdate) {
    INSTANCE_OR_ERROR(c);
    if (!fmu_check_interface(inst, FMU_ME, "fmiCompletedIntegratorStep")) return fmi1Error;
    *callEventUpdate = fmi1False;
    return fmi1OK;
}

/* One event iteration in the core's event mode, then back to continuous time. */
static fmi1Status event_update(FmuInstance* inst, const char* fn, fmi1EventInfo* eventInfo) {
    FmuEventResult ev;
    FmuStatus status = fmu_event_update(inst, fn, &ev);
    if (status >= FMU_ERROR) return (fmi1Status)status;
    eventInfo->iterationConverged = ev.discrete_states_need_update ? fmi1False : fmi1True;
    eventInfo->stateValueReferencesChanged = fmi1False;
    eventInfo->stateValuesChanged = ev.values_of_continuous_states_changed ? fmi1True : fmi1False;
    eventInfo->terminateSimulation = ev.terminate_simulation ? fmi1True : fmi1False;
    eventInfo->upcomingTimeEvent = ev.next_event_time_defined ? fmi1True : fmi1False;
    eventInfo->nextEventTime = ev.next_event_time;
    if (ev.discrete_states_need_update) return fmi1OK;
    return (fmi1Status)fmu_enter_continuous_mode(inst, fn);
}

fmi1Status FMI1(fmiInitialize)(fmi1Component c, fmi1Boolean toleranceControlled, fmi1Real relativeTolerance,
                               fmi1EventInfo* eventInfo) {
    (void)toleranceControlled;
    (void)relativeTolerance;
    INSTANCE_OR_ERROR(c);
    FmuStatus status = fmu_enter_initialization(inst, "fmiInitialize", inst->s.time);
    if (status >= FMU_ERROR) return (fmi1Status)status;
    status = fmu_exit_initialization(inst, "fmiInitialize");
    if (status >= FMU_ERROR) return (fmi1Status)status;
    return event_update(inst, "fmiInitialize", eventInfo);
}

fmi1Status FMI1(fmiEventUpdate)(fmi1Component c, fmi1Boolean intermediateResults, fmi1EventInfo* eventInfo) {
    (void)intermediateResults;
    INSTANCE_OR_ERROR(c);
    if (inst->s.mode == MODE_CONTINUOUS) {
        FmuStatus status = fmu_enter_event_mode(inst, "fmiEventUpdate");
        if (status >= FMU_ERROR) return (fmi1Status)status;
    }
    return event_update(inst, "fmiEventUpdate", eventInfo);
}

fmi1Status FMI1(fmiGetDerivatives)(fmi1Component c, fmi1Real derivatives[], size_t nx) {
    INSTANCE_OR_ERROR(c);
    return (fmi1Status)fmu_get_derivatives(inst, "fmiGetDerivatives", derivatives, nx);
}

fmi1Status FMI1(fmiGetEventIndicators)(fmi1Component c, fmi1Real eventIndicators[], size_t ni) {
    INSTANCE_OR_ERROR(c);
    return (fmi1Status)fmu_get_event_indicators(inst, "fmiGetEventIndicators", eventIndicators, ni);
}

fmi1Status FMI1(fmiGetContinuousStates)(fmi1Component c, fmi1Real states[], size_t nx) {
    INSTANCE_OR_ERROR(c);
    return (fmi1Status)fmu_get_states(inst, "fmiGetContinuousStates", states, nx);
}

fmi1Status FMI1(fmiGetNominalContinuousStates)(fmi1Component c, fmi1Real x_nominal[], size_t nx) {
    INSTANCE_OR_ERROR(c);
    return (fmi1Status)fmu_get_nominals(inst, "fmiGetNominalContinuousStates", x_nominal, nx);
}

fmi1Status FMI1(fmiGetStateValueReferences)(fmi1Component c, fmi1ValueReference vrx[], size_t nx) {
    INSTANCE_OR_ERROR(c);
    if (!fmu_check_count(inst, "fmiGetStateValueReferences", nx, MODEL_NX, "continuous states")) return fmi1Error;
    for (size_t k = 0; k < MODEL_NX; k++) {
        vrx[k] = fmi1UndefinedValueReference;
        for (unsigned vr = 0; vr < MODEL_N_VARS; vr++) {
            const FmuVariable* v = &MODEL_VARIABLES[vr];
            if (v->type == T_FLOAT64 && v->exposed && v->offset == MODEL_STATE_OFFSETS[k]) vrx[k] = vr;
        }
    }
    return fmi1OK;
}

fmi1Status FMI1(fmiTerminate)(fmi1Component c) {
    INSTANCE_OR_ERROR(c);
    return (fmi1Status)fmu_terminate(inst, "fmiTerminate");
}
