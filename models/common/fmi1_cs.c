/* FMI 1.0 co-simulation (stand-alone) wrapper over the fmu-bridge model core.
 * FMI 1.0 prefixes every function with the model identifier: <MODEL_IDENTIFIER>_fmiDoStep etc.
 * FMI 1.0 has no FMU state, no tunable parameters and no termination flag in co-simulation: a
 * termination request is reported as fmiDiscard from fmiDoStep (see models/README.md). */
#include <stddef.h>  /* fmi1Functions.h uses size_t without including it */

#include "fmi1Functions.h"
#include "fmu_core.h"

#include <stdlib.h>

#define FMI1_PASTE2(a, b) a##_##b
#define FMI1_PASTE(a, b) FMI1_PASTE2(a, b)
#define FMI1(name) FMI1_PASTE(MODEL_IDENTIFIER, name)
#define FMI1_EXPORT __attribute__((visibility("default")))
#define UNUSED(x) (void)(x)
#define INSTANCE_OR_ERROR(c)                      \
    FmuInstance* inst = (FmuInstance*)(c);         \
    if (inst == NULL) return fmi1Error

FMI1_EXPORT fmi1GetVersionTYPE FMI1(fmiGetVersion);
FMI1_EXPORT fmi1GetTypesPlatformTYPE FMI1(fmiGetTypesPlatform);
FMI1_EXPORT fmi1SetDebugLoggingTYPE FMI1(fmiSetDebugLogging);
FMI1_EXPORT fmi1GetRealTYPE FMI1(fmiGetReal);
FMI1_EXPORT fmi1GetIntegerTYPE FMI1(fmiGetInteger);
FMI1_EXPORT fmi1GetBooleanTYPE FMI1(fmiGetBoolean);
FMI1_EXPORT fmi1GetStringTYPE FMI1(fmiGetString);
FMI1_EXPORT fmi1SetRealTYPE FMI1(fmiSetReal);
FMI1_EXPORT fmi1SetIntegerTYPE FMI1(fmiSetInteger);
FMI1_EXPORT fmi1SetBooleanTYPE FMI1(fmiSetBoolean);
FMI1_EXPORT fmi1SetStringTYPE FMI1(fmiSetString);
FMI1_EXPORT fmi1InstantiateSlaveTYPE FMI1(fmiInstantiateSlave);
FMI1_EXPORT fmi1InitializeSlaveTYPE FMI1(fmiInitializeSlave);
FMI1_EXPORT fmi1TerminateSlaveTYPE FMI1(fmiTerminateSlave);
FMI1_EXPORT fmi1ResetSlaveTYPE FMI1(fmiResetSlave);
FMI1_EXPORT fmi1FreeSlaveInstanceTYPE FMI1(fmiFreeSlaveInstance);
FMI1_EXPORT fmi1SetRealInputDerivativesTYPE FMI1(fmiSetRealInputDerivatives);
FMI1_EXPORT fmi1GetRealOutputDerivativesTYPE FMI1(fmiGetRealOutputDerivatives);
FMI1_EXPORT fmi1CancelStepTYPE FMI1(fmiCancelStep);
FMI1_EXPORT fmi1DoStepTYPE FMI1(fmiDoStep);
FMI1_EXPORT fmi1GetStatusTYPE FMI1(fmiGetStatus);
FMI1_EXPORT fmi1GetRealStatusTYPE FMI1(fmiGetRealStatus);
FMI1_EXPORT fmi1GetIntegerStatusTYPE FMI1(fmiGetIntegerStatus);
FMI1_EXPORT fmi1GetBooleanStatusTYPE FMI1(fmiGetBooleanStatus);
FMI1_EXPORT fmi1GetStringStatusTYPE FMI1(fmiGetStringStatus);

typedef struct {
    FmuInstance core;   /* first member: an fmiComponent is also an FmuInstance* */
    fmi1CallbackFunctions callbacks;
} Fmi1Instance;

static void emit(FmuInstance* inst, FmuStatus status, const char* category, const char* message) {
    Fmi1Instance* w = (Fmi1Instance*)inst;
    if (w->callbacks.logger != NULL) w->callbacks.logger(inst, inst->name, (fmi1Status)status, category, message);
}

const char* FMI1(fmiGetVersion)(void) { return "1.0"; }

const char* FMI1(fmiGetTypesPlatform)(void) { return "standard32"; }

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

fmi1Component FMI1(fmiInstantiateSlave)(fmi1String instanceName, fmi1String fmuGUID, fmi1String fmuLocation,
                                        fmi1String mimeType, fmi1Real timeout, fmi1Boolean visible,
                                        fmi1Boolean interactive, fmi1CallbackFunctions functions,
                                        fmi1Boolean loggingOn) {
    UNUSED(fmuLocation);
    UNUSED(mimeType);
    UNUSED(timeout);
    UNUSED(visible);
    UNUSED(interactive);
    Fmi1Instance* w = calloc(1, sizeof *w);
    if (w == NULL) return NULL;
    w->callbacks = functions;
    w->core.fmi_version = 1;
    w->core.emit = emit;
    if (fmu_setup(&w->core, "fmiInstantiateSlave", instanceName, fmuGUID, FMU_CS, loggingOn != fmi1False) != FMU_OK) {
        fmu_teardown(&w->core);
        free(w);
        return NULL;
    }
    return w;
}

fmi1Status FMI1(fmiInitializeSlave)(fmi1Component c, fmi1Real tStart, fmi1Boolean StopTimeDefined, fmi1Real tStop) {
    UNUSED(StopTimeDefined);
    UNUSED(tStop);
    INSTANCE_OR_ERROR(c);
    FmuStatus status = fmu_enter_initialization(inst, "fmiInitializeSlave", tStart);
    if (status >= FMU_ERROR) return (fmi1Status)status;
    return (fmi1Status)fmu_exit_initialization(inst, "fmiInitializeSlave");
}

fmi1Status FMI1(fmiTerminateSlave)(fmi1Component c) {
    INSTANCE_OR_ERROR(c);
    return (fmi1Status)fmu_terminate(inst, "fmiTerminateSlave");
}

fmi1Status FMI1(fmiResetSlave)(fmi1Component c) {
    INSTANCE_OR_ERROR(c);
    return (fmi1Status)fmu_reset(inst, "fmiResetSlave");
}

void FMI1(fmiFreeSlaveInstance)(fmi1Component c) {
    if (c == NULL) return;
    fmu_teardown((FmuInstance*)c);
    free(c);
}

fmi1Status FMI1(fmiSetRealInputDerivatives)(fmi1Component c, const fmi1ValueReference vr[], size_t nvr,
                                            const fmi1Integer order[], const fmi1Real value[]) {
    UNUSED(vr);
    UNUSED(nvr);
    UNUSED(order);
    UNUSED(value);
    INSTANCE_OR_ERROR(c);
    return (fmi1Status)fmu_unsupported(inst, "fmiSetRealInputDerivatives", "canInterpolateInputs is false");
}

fmi1Status FMI1(fmiGetRealOutputDerivatives)(fmi1Component c, const fmi1ValueReference vr[], size_t nvr,
                                             const fmi1Integer order[], fmi1Real value[]) {
    UNUSED(vr);
    UNUSED(nvr);
    UNUSED(order);
    UNUSED(value);
    INSTANCE_OR_ERROR(c);
    return (fmi1Status)fmu_unsupported(inst, "fmiGetRealOutputDerivatives", "maxOutputDerivativeOrder is 0");
}

fmi1Status FMI1(fmiCancelStep)(fmi1Component c) {
    INSTANCE_OR_ERROR(c);
    return (fmi1Status)fmu_unsupported(inst, "fmiCancelStep", "fmiDoStep never returns fmiPending");
}

fmi1Status FMI1(fmiDoStep)(fmi1Component c, fmi1Real currentCommunicationPoint, fmi1Real communicationStepSize,
                           fmi1Boolean newStep) {
    UNUSED(newStep);
    INSTANCE_OR_ERROR(c);
    FmuStatus status = fmu_do_step(inst, "fmiDoStep", currentCommunicationPoint, communicationStepSize);
    if (status <= FMU_WARNING && inst->s.terminate_requested) return fmi1Discard;
    return (fmi1Status)status;
}

fmi1Status FMI1(fmiGetStatus)(fmi1Component c, const fmi1StatusKind s, fmi1Status* value) {
    UNUSED(s);
    UNUSED(value);
    INSTANCE_OR_ERROR(c);
    return fmi1Discard;   /* fmiDoStep is synchronous: there is no pending status to report */
}

fmi1Status FMI1(fmiGetRealStatus)(fmi1Component c, const fmi1StatusKind s, fmi1Real* value) {
    INSTANCE_OR_ERROR(c);
    if (s != fmi1LastSuccessfulTime) return fmi1Discard;
    *value = inst->s.time;
    return fmi1OK;
}

fmi1Status FMI1(fmiGetIntegerStatus)(fmi1Component c, const fmi1StatusKind s, fmi1Integer* value) {
    UNUSED(s);
    UNUSED(value);
    INSTANCE_OR_ERROR(c);
    return fmi1Discard;
}

fmi1Status FMI1(fmiGetBooleanStatus)(fmi1Component c, const fmi1StatusKind s, fmi1Boolean* value) {
    UNUSED(s);
    UNUSED(value);
    INSTANCE_OR_ERROR(c);
    return fmi1Discard;
}

fmi1Status FMI1(fmiGetStringStatus)(fmi1Component c, const fmi1StatusKind s, fmi1String* value) {
    UNUSED(s);
    UNUSED(value);
    INSTANCE_OR_ERROR(c);
    return fmi1Discard;
}
