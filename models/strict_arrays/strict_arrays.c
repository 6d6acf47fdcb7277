/* strict_arrays: an FMI 3.0 model (co-simulation and model exchange) that follows the standard's
 * array rules to the letter, written without the shared framework of models/common.
 *
 *   n            UInt64 structural parameter (fixed): the array size, settable in configuration mode only
 *   k            Float64 parameter (fixed): the decay rate
 *   u[n]         Float64 input array, u_i = i until set
 *   x[n]         Float64 continuous state array, x_i(0) = 0.5 i unless set before initialisation
 *   der(x)[n]    dx_i/dt = u_i - k x_i
 *   y[2,n]       Float64 output array: row 1 is x, row 2 is der(x)
 *   total        Float64 output: the sum of x
 *   A[2,2]       Float64 parameter (fixed) array, identity at the start; only its determinant is used
 *   det_A        Float64 local (fixed, calculated): the determinant of A
 *
 * With u held: x_i(t) = u_i/k + (x_i(t0) - u_i/k) exp(-k (t - t0)). Co-simulation steps with this
 * closed form; model exchange leaves the integration to the importer.
 *
 * Every fmi3Get/SetFloat64 and fmi3Get/SetUInt64 call must pass nValues equal to the sum of the
 * element counts of its value references (an array variable counts all its elements); anything
 * else is logged and answered with fmi3Error, as a strict exporter does. So is a value reference of
 * the wrong type, and a set the variable's causality and variability do not allow in the current
 * mode (n only in configuration mode, k and x only before the end of initialisation). */
#include <math.h>
#include <stdarg.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi3Functions.h"

#define VR_TIME 0
#define VR_N 1
#define VR_K 2
#define VR_U 3
#define VR_X 4
#define VR_DX 5
#define VR_Y 6
#define VR_TOTAL 7
#define VR_A 8
#define VR_DET_A 9
#define N_START 3
#define N_MAX 100000
#define UNUSED(x) (void)(x)

typedef enum { INSTANTIATED, CONFIGURATION, INITIALIZATION, EVENT, CONTINUOUS, STEP, TERMINATED } Mode;

typedef struct {
    Mode mode;
    bool cs;
    double time;
    uint64_t n;
    double k;
    double* u;
    double* x;
    double a[4]; /* A[2,2], row-major */
} State;

typedef struct {
    State s;
    fmi3InstanceEnvironment environment;
    fmi3LogMessageCallback log;
} Instance;

static void say(Instance* m, fmi3Status status, const char* format, ...) {
    if (m->log == NULL) return;
    char text[512];
    va_list args;
    va_start(args, format);
    vsnprintf(text, sizeof text, format, args);
    va_end(args);
    m->log(m->environment, status, status == fmi3Error ? "logStatusError" : "logAll", text);
}

static fmi3Status fail(Instance* m, const char* format, ...) {
    if (m->log != NULL) {
        char text[512];
        va_list args;
        va_start(args, format);
        vsnprintf(text, sizeof text, format, args);
        va_end(args);
        m->log(m->environment, fmi3Error, "logStatusError", text);
    }
    return fmi3Error;
}

/* Arrays sized n, u_i = i and x_i = 0.5 i (1-based i): the state after instantiation or configuration. */
static bool size_arrays(State* s, uint64_t n) {
    double* u = realloc(s->u, sizeof(double) * (size_t)n);
    if (u != NULL) s->u = u;
    double* x = realloc(s->x, sizeof(double) * (size_t)n);
    if (x != NULL) s->x = x;
    if (u == NULL || x == NULL) return false;
    s->n = n;
    for (uint64_t i = 0; i < n; i++) {
        s->u[i] = (double)(i + 1);
        s->x[i] = 0.5 * (double)(i + 1);
    }
    return true;
}

static size_t count(const State* s, fmi3ValueReference vr) {
    switch (vr) {
        case VR_U: case VR_X: case VR_DX: return (size_t)s->n;
        case VR_Y: return 2 * (size_t)s->n;
        case VR_A: return 4;
        default: return 1;
    }
}

static bool known(fmi3ValueReference vr) { return vr <= VR_DET_A; }

static void identity(double a[4]) {
    a[0] = a[3] = 1.0;
    a[1] = a[2] = 0.0;
}

/* The strict rule: nValues is the sum of the element counts of the value references. */
static bool counts_match(Instance* m, const char* fn, const fmi3ValueReference vr[], size_t nvr, size_t nValues,
                         bool uint64) {
    size_t expected = 0;
    for (size_t j = 0; j < nvr; j++) {
        if (!known(vr[j]) || (vr[j] == VR_N) != uint64) {
            fail(m, "%s: value reference %u is not a variable of this type", fn, (unsigned)vr[j]);
            return false;
        }
        expected += count(&m->s, vr[j]);
    }
    if (expected != nValues) {
        fail(m, "%s: Expected nValues = %zu but was %zu.", fn, expected, nValues);
        return false;
    }
    return true;
}

static double derivative(const State* s, size_t i) { return s->u[i] - s->k * s->x[i]; }

/* ---- instances ---------------------------------------------------------------------------------- */

static Instance* instantiate(fmi3InstanceEnvironment env, fmi3LogMessageCallback log, bool cs) {
    Instance* m = calloc(1, sizeof *m);
    if (m == NULL) return NULL;
    m->environment = env;
    m->log = log;
    m->s.cs = cs;
    m->s.k = 1.0;
    identity(m->s.a);
    if (!size_arrays(&m->s, N_START)) {
        free(m->s.u);
        free(m->s.x);
        free(m);
        return NULL;
    }
    return m;
}

const char* fmi3GetVersion(void) { return fmi3Version; }

fmi3Status fmi3SetDebugLogging(fmi3Instance instance, fmi3Boolean loggingOn, size_t nCategories,
                               const fmi3String categories[]) {
    UNUSED(instance);
    UNUSED(loggingOn);
    UNUSED(nCategories);
    UNUSED(categories);
    return fmi3OK;
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage) {
    UNUSED(instanceName);
    UNUSED(instantiationToken);
    UNUSED(resourcePath);
    UNUSED(visible);
    UNUSED(loggingOn);
    return instantiate(instanceEnvironment, logMessage, false);
}

fmi3Instance fmi3InstantiateCoSimulation(fmi3String instanceName, fmi3String instantiationToken,
                                         fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                         fmi3Boolean eventModeUsed, fmi3Boolean earlyReturnAllowed,
                                         const fmi3ValueReference requiredIntermediateVariables[],
                                         size_t nRequiredIntermediateVariables,
                                         fmi3InstanceEnvironment instanceEnvironment,
                                         fmi3LogMessageCallback logMessage,
                                         fmi3IntermediateUpdateCallback intermediateUpdate) {
    UNUSED(instanceName);
    UNUSED(instantiationToken);
    UNUSED(resourcePath);
    UNUSED(visible);
    UNUSED(loggingOn);
    UNUSED(earlyReturnAllowed);
    UNUSED(requiredIntermediateVariables);
    UNUSED(nRequiredIntermediateVariables);
    UNUSED(intermediateUpdate);
    if (eventModeUsed) {
        if (logMessage != NULL)
            logMessage(instanceEnvironment, fmi3Error, "logStatusError", "event mode is not supported");
        return NULL;
    }
    return instantiate(instanceEnvironment, logMessage, true);
}

fmi3Instance fmi3InstantiateScheduledExecution(fmi3String instanceName, fmi3String instantiationToken,
                                               fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                               fmi3InstanceEnvironment instanceEnvironment,
                                               fmi3LogMessageCallback logMessage,
                                               fmi3ClockUpdateCallback clockUpdate,
                                               fmi3LockPreemptionCallback lockPreemption,
                                               fmi3UnlockPreemptionCallback unlockPreemption) {
    UNUSED(instanceName);
    UNUSED(instantiationToken);
    UNUSED(resourcePath);
    UNUSED(visible);
    UNUSED(loggingOn);
    UNUSED(clockUpdate);
    UNUSED(lockPreemption);
    UNUSED(unlockPreemption);
    if (logMessage != NULL)
        logMessage(instanceEnvironment, fmi3Error, "logStatusError", "scheduled execution is not supported");
    return NULL;
}

void fmi3FreeInstance(fmi3Instance instance) {
    Instance* m = (Instance*)instance;
    if (m == NULL) return;
    free(m->s.u);
    free(m->s.x);
    free(m);
}

#define INSTANCE Instance* m = (Instance*)instance; if (m == NULL) return fmi3Error

static fmi3Status in_mode(Instance* m, const char* fn, Mode wanted) {
    if (m->s.mode == wanted) return fmi3OK;
    return fail(m, "%s: not allowed in mode %d (expected %d)", fn, (int)m->s.mode, (int)wanted);
}

fmi3Status fmi3EnterConfigurationMode(fmi3Instance instance) {
    INSTANCE;
    if (in_mode(m, "fmi3EnterConfigurationMode", INSTANTIATED) != fmi3OK) return fmi3Error;
    m->s.mode = CONFIGURATION;
    return fmi3OK;
}

fmi3Status fmi3ExitConfigurationMode(fmi3Instance instance) {
    INSTANCE;
    if (in_mode(m, "fmi3ExitConfigurationMode", CONFIGURATION) != fmi3OK) return fmi3Error;
    m->s.mode = INSTANTIATED;
    say(m, fmi3OK, "configured: n = %llu", (unsigned long long)m->s.n);
    return fmi3OK;
}

fmi3Status fmi3EnterInitializationMode(fmi3Instance instance, fmi3Boolean toleranceDefined, fmi3Float64 tolerance,
                                       fmi3Float64 startTime, fmi3Boolean stopTimeDefined, fmi3Float64 stopTime) {
    INSTANCE;
    UNUSED(toleranceDefined);
    UNUSED(tolerance);
    UNUSED(stopTimeDefined);
    UNUSED(stopTime);
    if (in_mode(m, "fmi3EnterInitializationMode", INSTANTIATED) != fmi3OK) return fmi3Error;
    m->s.time = startTime;
    m->s.mode = INITIALIZATION;
    return fmi3OK;
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance instance) {
    INSTANCE;
    if (in_mode(m, "fmi3ExitInitializationMode", INITIALIZATION) != fmi3OK) return fmi3Error;
    m->s.mode = m->s.cs ? STEP : EVENT;
    return fmi3OK;
}

fmi3Status fmi3EnterEventMode(fmi3Instance instance) {
    INSTANCE;
    if (m->s.cs) return fail(m, "fmi3EnterEventMode: co-simulation without event mode");
    m->s.mode = EVENT;
    return fmi3OK;
}

fmi3Status fmi3Terminate(fmi3Instance instance) {
    INSTANCE;
    m->s.mode = TERMINATED;
    return fmi3OK;
}

fmi3Status fmi3Reset(fmi3Instance instance) {
    INSTANCE;
    m->s.mode = INSTANTIATED;
    m->s.time = 0.0;
    m->s.k = 1.0;
    identity(m->s.a);
    return size_arrays(&m->s, N_START) ? fmi3OK : fail(m, "fmi3Reset: out of memory");
}

/* ---- Float64 and UInt64 --------------------------------------------------------------------------- */

static bool readable(Instance* m, const char* fn) {
    if (m->s.mode != CONFIGURATION) return true;
    fail(m, "%s: only structural parameters can be read in configuration mode", fn);
    return false;
}

fmi3Status fmi3GetFloat64(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, fmi3Float64 values[],
                          size_t nValues) {
    INSTANCE;
    if (!counts_match(m, "fmi3GetFloat64", vr, nvr, nValues, false) || !readable(m, "fmi3GetFloat64"))
        return fmi3Error;
    const State* s = &m->s;
    size_t at = 0;
    for (size_t j = 0; j < nvr; j++) {
        size_t n = (size_t)s->n;
        double total = 0.0;
        switch (vr[j]) {
            case VR_TIME: values[at++] = s->time; break;
            case VR_K: values[at++] = s->k; break;
            case VR_A: memcpy(values + at, s->a, sizeof s->a); at += 4; break;
            case VR_DET_A: values[at++] = s->a[0] * s->a[3] - s->a[1] * s->a[2]; break;
            case VR_U: memcpy(values + at, s->u, n * sizeof(double)); at += n; break;
            case VR_X: memcpy(values + at, s->x, n * sizeof(double)); at += n; break;
            case VR_DX: for (size_t i = 0; i < n; i++) values[at++] = derivative(s, i); break;
            case VR_Y: /* row-major: the first row is x, the second der(x) */
                memcpy(values + at, s->x, n * sizeof(double));
                at += n;
                for (size_t i = 0; i < n; i++) values[at++] = derivative(s, i);
                break;
            default: /* VR_TOTAL */
                for (size_t i = 0; i < n; i++) total += s->x[i];
                values[at++] = total;
        }
    }
    return fmi3OK;
}

static bool before_end_of_initialization(Mode mode) { return mode == INSTANTIATED || mode == INITIALIZATION; }

fmi3Status fmi3SetFloat64(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                          const fmi3Float64 values[], size_t nValues) {
    INSTANCE;
    if (!counts_match(m, "fmi3SetFloat64", vr, nvr, nValues, false)) return fmi3Error;
    State* s = &m->s;
    for (size_t j = 0; j < nvr; j++) {
        bool early = vr[j] == VR_K || vr[j] == VR_X || vr[j] == VR_A;
        bool allowed = vr[j] == VR_U ? s->mode != CONFIGURATION && s->mode != TERMINATED
                                     : early && before_end_of_initialization(s->mode);
        if (!allowed) return fail(m, "fmi3SetFloat64: value reference %u cannot be set in mode %d", vr[j], s->mode);
    }
    size_t at = 0;
    for (size_t j = 0; j < nvr; j++) {
        size_t n = (size_t)s->n;
        switch (vr[j]) {
            case VR_K: s->k = values[at++]; break;
            case VR_A: memcpy(s->a, values + at, sizeof s->a); at += 4; break;
            case VR_U: memcpy(s->u, values + at, n * sizeof(double)); at += n; break;
            default: memcpy(s->x, values + at, n * sizeof(double)); at += n; /* VR_X */
        }
    }
    return fmi3OK;
}

fmi3Status fmi3GetUInt64(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, fmi3UInt64 values[],
                         size_t nValues) {
    INSTANCE;
    if (!counts_match(m, "fmi3GetUInt64", vr, nvr, nValues, true)) return fmi3Error;
    for (size_t j = 0; j < nvr; j++) values[j] = m->s.n;
    return fmi3OK;
}

fmi3Status fmi3SetUInt64(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, const fmi3UInt64 values[],
                         size_t nValues) {
    INSTANCE;
    if (!counts_match(m, "fmi3SetUInt64", vr, nvr, nValues, true)) return fmi3Error;
    if (m->s.mode != CONFIGURATION)
        return fail(m, "fmi3SetUInt64: n is a structural parameter: set it in configuration mode");
    for (size_t j = 0; j < nvr; j++) {
        if (values[j] < 1 || values[j] > N_MAX)
            return fail(m, "fmi3SetUInt64: n = %llu is outside [1, %d]", (unsigned long long)values[j], N_MAX);
        if (!size_arrays(&m->s, values[j])) return fail(m, "fmi3SetUInt64: out of memory");
    }
    return fmi3OK;
}

/* Types this model has no variables of: every value reference is of another type. */
#define NO_VARIABLES(NAME, CTYPE, CONST)                                                                    \
    fmi3Status NAME(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, CONST CTYPE values[], \
                    size_t nValues) {                                                                       \
        INSTANCE;                                                                                           \
        UNUSED(values);                                                                                     \
        UNUSED(nValues);                                                                                    \
        return nvr == 0 ? fmi3OK : fail(m, #NAME ": value reference %u is not a variable of this type", vr[0]); \
    }
NO_VARIABLES(fmi3GetFloat32, fmi3Float32, )
NO_VARIABLES(fmi3GetInt8, fmi3Int8, )
NO_VARIABLES(fmi3GetUInt8, fmi3UInt8, )
NO_VARIABLES(fmi3GetInt16, fmi3Int16, )
NO_VARIABLES(fmi3GetUInt16, fmi3UInt16, )
NO_VARIABLES(fmi3GetInt32, fmi3Int32, )
NO_VARIABLES(fmi3GetUInt32, fmi3UInt32, )
NO_VARIABLES(fmi3GetInt64, fmi3Int64, )
NO_VARIABLES(fmi3GetBoolean, fmi3Boolean, )
NO_VARIABLES(fmi3GetString, fmi3String, )
NO_VARIABLES(fmi3SetFloat32, fmi3Float32, const)
NO_VARIABLES(fmi3SetInt8, fmi3Int8, const)
NO_VARIABLES(fmi3SetUInt8, fmi3UInt8, const)
NO_VARIABLES(fmi3SetInt16, fmi3Int16, const)
NO_VARIABLES(fmi3SetUInt16, fmi3UInt16, const)
NO_VARIABLES(fmi3SetInt32, fmi3Int32, const)
NO_VARIABLES(fmi3SetUInt32, fmi3UInt32, const)
NO_VARIABLES(fmi3SetInt64, fmi3Int64, const)
NO_VARIABLES(fmi3SetBoolean, fmi3Boolean, const)
NO_VARIABLES(fmi3SetString, fmi3String, const)

fmi3Status fmi3GetBinary(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, size_t valueSizes[],
                         fmi3Binary values[], size_t nValues) {
    INSTANCE;
    UNUSED(valueSizes);
    UNUSED(values);
    UNUSED(nValues);
    return nvr == 0 ? fmi3OK : fail(m, "fmi3GetBinary: value reference %u is not a Binary", vr[0]);
}

fmi3Status fmi3SetBinary(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, const size_t valueSizes[],
                         const fmi3Binary values[], size_t nValues) {
    INSTANCE;
    UNUSED(valueSizes);
    UNUSED(values);
    UNUSED(nValues);
    return nvr == 0 ? fmi3OK : fail(m, "fmi3SetBinary: value reference %u is not a Binary", vr[0]);
}

fmi3Status fmi3GetClock(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, fmi3Clock values[]) {
    INSTANCE;
    UNUSED(values);
    return nvr == 0 ? fmi3OK : fail(m, "fmi3GetClock: value reference %u is not a clock", vr[0]);
}

fmi3Status fmi3SetClock(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, const fmi3Clock values[]) {
    INSTANCE;
    UNUSED(values);
    return nvr == 0 ? fmi3OK : fail(m, "fmi3SetClock: value reference %u is not a clock", vr[0]);
}

/* ---- FMU state: a copy of the instance's state, arrays included ------------------------------------ */

fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState* FMUState) {
    INSTANCE;
    State* copy = *FMUState != NULL ? (State*)*FMUState : calloc(1, sizeof *copy);
    if (copy == NULL) return fail(m, "fmi3GetFMUState: out of memory");
    double* u = copy->u;
    double* x = copy->x;
    *copy = m->s;
    copy->u = realloc(u, sizeof(double) * (size_t)m->s.n);
    copy->x = realloc(x, sizeof(double) * (size_t)m->s.n);
    if (copy->u == NULL || copy->x == NULL) return fail(m, "fmi3GetFMUState: out of memory");
    memcpy(copy->u, m->s.u, sizeof(double) * (size_t)m->s.n);
    memcpy(copy->x, m->s.x, sizeof(double) * (size_t)m->s.n);
    *FMUState = copy;
    return fmi3OK;
}

fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState FMUState) {
    INSTANCE;
    const State* saved = (const State*)FMUState;
    if (saved == NULL) return fail(m, "fmi3SetFMUState: no state");
    double* u = m->s.u;
    double* x = m->s.x;
    m->s = *saved;
    m->s.u = u;
    m->s.x = x;
    uint64_t n = saved->n;
    if (!size_arrays(&m->s, n)) return fail(m, "fmi3SetFMUState: out of memory");
    memcpy(m->s.u, saved->u, sizeof(double) * (size_t)n);
    memcpy(m->s.x, saved->x, sizeof(double) * (size_t)n);
    return fmi3OK;
}

fmi3Status fmi3FreeFMUState(fmi3Instance instance, fmi3FMUState* FMUState) {
    UNUSED(instance);
    if (FMUState == NULL || *FMUState == NULL) return fmi3OK;
    State* s = (State*)*FMUState;
    free(s->u);
    free(s->x);
    free(s);
    *FMUState = NULL;
    return fmi3OK;
}

#define UNSUPPORTED(SIGNATURE, NAME) \
    fmi3Status SIGNATURE {           \
        INSTANCE;                    \
        return fail(m, NAME ": not supported by this model"); \
    }
UNSUPPORTED(fmi3SerializedFMUStateSize(fmi3Instance instance, fmi3FMUState FMUState, size_t* size),
            "fmi3SerializedFMUStateSize")
UNSUPPORTED(fmi3SerializeFMUState(fmi3Instance instance, fmi3FMUState FMUState, fmi3Byte serializedState[],
                                  size_t size),
            "fmi3SerializeFMUState")
UNSUPPORTED(fmi3DeserializeFMUState(fmi3Instance instance, const fmi3Byte serializedState[], size_t size,
                                    fmi3FMUState* FMUState),
            "fmi3DeserializeFMUState")
UNSUPPORTED(fmi3GetNumberOfVariableDependencies(fmi3Instance instance, fmi3ValueReference valueReference,
                                                size_t* nDependencies),
            "fmi3GetNumberOfVariableDependencies")
UNSUPPORTED(fmi3GetVariableDependencies(fmi3Instance instance, fmi3ValueReference dependent,
                                        size_t elementIndicesOfDependent[], fmi3ValueReference independents[],
                                        size_t elementIndicesOfIndependents[], fmi3DependencyKind dependencyKinds[],
                                        size_t nDependencies),
            "fmi3GetVariableDependencies")
UNSUPPORTED(fmi3GetDirectionalDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[], size_t nUnknowns,
                                         const fmi3ValueReference knowns[], size_t nKnowns, const fmi3Float64 seed[],
                                         size_t nSeed, fmi3Float64 sensitivity[], size_t nSensitivity),
            "fmi3GetDirectionalDerivative")
UNSUPPORTED(fmi3GetAdjointDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[], size_t nUnknowns,
                                     const fmi3ValueReference knowns[], size_t nKnowns, const fmi3Float64 seed[],
                                     size_t nSeed, fmi3Float64 sensitivity[], size_t nSensitivity),
            "fmi3GetAdjointDerivative")
UNSUPPORTED(fmi3GetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                   fmi3Float64 intervals[], fmi3IntervalQualifier qualifiers[]),
            "fmi3GetIntervalDecimal")
UNSUPPORTED(fmi3GetIntervalFraction(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                    fmi3UInt64 counters[], fmi3UInt64 resolutions[],
                                    fmi3IntervalQualifier qualifiers[]),
            "fmi3GetIntervalFraction")
UNSUPPORTED(fmi3GetShiftDecimal(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                fmi3Float64 shifts[]),
            "fmi3GetShiftDecimal")
UNSUPPORTED(fmi3GetShiftFraction(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                 fmi3UInt64 counters[], fmi3UInt64 resolutions[]),
            "fmi3GetShiftFraction")
UNSUPPORTED(fmi3SetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                   const fmi3Float64 intervals[]),
            "fmi3SetIntervalDecimal")
UNSUPPORTED(fmi3SetIntervalFraction(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                    const fmi3UInt64 counters[], const fmi3UInt64 resolutions[]),
            "fmi3SetIntervalFraction")
UNSUPPORTED(fmi3SetShiftDecimal(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                const fmi3Float64 shifts[]),
            "fmi3SetShiftDecimal")
UNSUPPORTED(fmi3SetShiftFraction(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                 const fmi3UInt64 counters[], const fmi3UInt64 resolutions[]),
            "fmi3SetShiftFraction")
UNSUPPORTED(fmi3GetOutputDerivatives(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                     const fmi3Int32 orders[], fmi3Float64 values[], size_t nValues),
            "fmi3GetOutputDerivatives")
UNSUPPORTED(fmi3ActivateModelPartition(fmi3Instance instance, fmi3ValueReference clockReference,
                                       fmi3Float64 activationTime),
            "fmi3ActivateModelPartition")

fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance instance) {
    INSTANCE;
    return fmi3OK;
}

fmi3Status fmi3UpdateDiscreteStates(fmi3Instance instance, fmi3Boolean* discreteStatesNeedUpdate,
                                    fmi3Boolean* terminateSimulation, fmi3Boolean* nominalsOfContinuousStatesChanged,
                                    fmi3Boolean* valuesOfContinuousStatesChanged, fmi3Boolean* nextEventTimeDefined,
                                    fmi3Float64* nextEventTime) {
    INSTANCE;
    *discreteStatesNeedUpdate = fmi3False;
    *terminateSimulation = fmi3False;
    *nominalsOfContinuousStatesChanged = fmi3False;
    *valuesOfContinuousStatesChanged = fmi3False;
    *nextEventTimeDefined = fmi3False;
    *nextEventTime = 0.0;
    return fmi3OK;
}

/* ---- model exchange: the n elements of x are the continuous states ----------------------------------- */

fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance instance) {
    INSTANCE;
    m->s.mode = CONTINUOUS;
    return fmi3OK;
}

fmi3Status fmi3CompletedIntegratorStep(fmi3Instance instance, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean* enterEventMode, fmi3Boolean* terminateSimulation) {
    INSTANCE;
    UNUSED(noSetFMUStatePriorToCurrentPoint);
    *enterEventMode = fmi3False;
    *terminateSimulation = fmi3False;
    return fmi3OK;
}

fmi3Status fmi3SetTime(fmi3Instance instance, fmi3Float64 time) {
    INSTANCE;
    m->s.time = time;
    return fmi3OK;
}

static bool states_match(Instance* m, const char* fn, size_t given) {
    if (given == (size_t)m->s.n) return true;
    fail(m, "%s: Expected nContinuousStates = %llu but was %zu.", fn, (unsigned long long)m->s.n, given);
    return false;
}

fmi3Status fmi3SetContinuousStates(fmi3Instance instance, const fmi3Float64 continuousStates[],
                                   size_t nContinuousStates) {
    INSTANCE;
    if (!states_match(m, "fmi3SetContinuousStates", nContinuousStates)) return fmi3Error;
    memcpy(m->s.x, continuousStates, nContinuousStates * sizeof(double));
    return fmi3OK;
}

fmi3Status fmi3GetContinuousStates(fmi3Instance instance, fmi3Float64 continuousStates[],
                                   size_t nContinuousStates) {
    INSTANCE;
    if (!states_match(m, "fmi3GetContinuousStates", nContinuousStates)) return fmi3Error;
    memcpy(continuousStates, m->s.x, nContinuousStates * sizeof(double));
    return fmi3OK;
}

fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance instance, fmi3Float64 derivatives[],
                                             size_t nContinuousStates) {
    INSTANCE;
    if (!states_match(m, "fmi3GetContinuousStateDerivatives", nContinuousStates)) return fmi3Error;
    for (size_t i = 0; i < nContinuousStates; i++) derivatives[i] = derivative(&m->s, i);
    return fmi3OK;
}

fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance instance, fmi3Float64 nominals[],
                                             size_t nContinuousStates) {
    INSTANCE;
    if (!states_match(m, "fmi3GetNominalsOfContinuousStates", nContinuousStates)) return fmi3Error;
    for (size_t i = 0; i < nContinuousStates; i++) nominals[i] = 1.0;
    return fmi3OK;
}

fmi3Status fmi3GetEventIndicators(fmi3Instance instance, fmi3Float64 eventIndicators[], size_t nEventIndicators) {
    INSTANCE;
    UNUSED(eventIndicators);
    return nEventIndicators == 0 ? fmi3OK : fail(m, "fmi3GetEventIndicators: this model has none");
}

fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance instance, size_t* nEventIndicators) {
    INSTANCE;
    *nEventIndicators = 0;
    return fmi3OK;
}

fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance instance, size_t* nContinuousStates) {
    INSTANCE;
    *nContinuousStates = (size_t)m->s.n;
    return fmi3OK;
}

/* ---- co-simulation: the closed form over each step ------------------------------------------------- */

fmi3Status fmi3EnterStepMode(fmi3Instance instance) {
    INSTANCE;
    m->s.mode = STEP;
    return fmi3OK;
}

fmi3Status fmi3DoStep(fmi3Instance instance, fmi3Float64 currentCommunicationPoint,
                      fmi3Float64 communicationStepSize, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                      fmi3Boolean* eventHandlingNeeded, fmi3Boolean* terminateSimulation, fmi3Boolean* earlyReturn,
                      fmi3Float64* lastSuccessfulTime) {
    INSTANCE;
    UNUSED(noSetFMUStatePriorToCurrentPoint);
    if (in_mode(m, "fmi3DoStep", STEP) != fmi3OK) return fmi3Error;
    State* s = &m->s;
    double decay = exp(-s->k * communicationStepSize);
    for (size_t i = 0; i < (size_t)s->n; i++) {
        if (s->k != 0.0) {
            double rest = s->u[i] / s->k;
            s->x[i] = rest + (s->x[i] - rest) * decay;
        } else {
            s->x[i] += s->u[i] * communicationStepSize;
        }
    }
    s->time = currentCommunicationPoint + communicationStepSize;
    *eventHandlingNeeded = fmi3False;
    *terminateSimulation = fmi3False;
    *earlyReturn = fmi3False;
    *lastSuccessfulTime = s->time;
    return fmi3OK;
}
