/* clocks3: an FMI 3.0 model with one input Clock of every time-based kind, a triggered input Clock,
 * a triggered output Clock and a clocked controller, for co-simulation with event mode and for
 * scheduled execution (the same binary; modelDescription.xml says which interface an archive offers).
 *
 * Plant: x' = -x + u, integrated exactly in co-simulation and scheduled execution (u is held between
 * the controller's ticks); in model exchange the importer integrates it (state x, derivative der(x)).
 * Controller (Clock c_ctrl, constant, every 0.1 s from 0): u := gain * (r - x).
 *
 * Clocks and their ticks (t_start = 0, all closed forms):
 *   c_ctrl      constant  interval 0.1, shift 0          -> 0.1 k
 *   c_const     constant  interval 0.3, shift 0.1        -> 0.1 + 0.3 k
 *   c_fixed     fixed     intervalDecimal 0.25 (the importer may set another in initialization mode),
 *                         shift 0.05                     -> 0.05 + T k
 *   c_calc      fixed     no intervalDecimal: interval = period, shift = period / 2, computed by the FMU
 *                         from the fixed parameter period -> period / 2 + period k
 *   c_tunable   tunable   no intervalDecimal: interval = tunable_period (a tunable parameter), shift 0;
 *                         a new value set in event mode starts a new interval from that event
 *   c_changing  changing  intervals 0.1, 0.2, 0.3, ...   -> 0.05 (k + 1)(k + 2)
 *   c_countdown countdown first 0.05 s after the start; then armed 0.05 s after each c_const tick
 *                         (its interval is not yet known between its tick and the next c_const tick)
 *   trigger     triggered input: whenever the importer activates it
 *   c_out       triggered output: at every second c_const tick
 * Clocked outputs n_<clock> count each clock's ticks and t_<clock> hold the time of the last one.
 * Co-simulation and model exchange: a time event of the FMU's own at alarm_time (announced as
 * nextEventTime unless announce_alarm is 0; co-simulation: eventHandlingNeeded from the doStep that
 * passes it) sets t_alarm to the time it was handled at. */
#include "fmi3Functions.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#ifndef CLOCKS3_TOKEN
#define CLOCKS3_TOKEN "{5f0c1c3e-0c1f-4c55-9a0e-c10c4b3c1a03}"
#endif

enum { C_CTRL = 1, C_CONST, C_FIXED, C_CALC, C_TUNABLE, C_CHANGING, C_COUNTDOWN, C_TRIGGER, C_OUT };
#define N_INPUT_CLOCKS 8 /* value references 1..8; c_out is 9 */
/* Float64 value references */
enum { VR_TIME = 0, VR_X = 20, VR_U, VR_R, VR_GAIN, VR_X0, VR_PERIOD, VR_TUNABLE_PERIOD, VR_ALARM_TIME };
#define VR_ANNOUNCE_ALARM 29
#define VR_T_ALARM 49
#define VR_DER_X 28
#define VR_N_FIRST 31 /* Int32 n_<clock>: 31..39 (c_ctrl .. c_out) */
#define VR_T_FIRST 41 /* Float64 t_<clock>: 41..48 (c_ctrl .. trigger) */

typedef enum { INSTANTIATED, INITIALIZATION, EVENT, STEP, CONTINUOUS, CLOCK_ACTIVATION, TERMINATED } Mode;

typedef struct {
    double time;
    Mode mode;
    double x, u, r, gain, x0, period, tunable_period, fixed_interval, alarm_time, t_alarm, announce_alarm;
    bool alarm_fired;
    bool active[N_INPUT_CLOCKS + 2];
    bool out_clock;
    bool evaluated;
    int last_partition; /* scheduled execution: the partition that ran last */
    int tunable_qualifier, changing_qualifier, countdown_qualifier;
    double changing_interval, countdown_interval;
    int changing_count;
    int32_t n[N_INPUT_CLOCKS + 2];
    double t_last[N_INPUT_CLOCKS + 1];
} State;

typedef struct {
    State s;
    bool scheduled;
    fmi3InstanceEnvironment env;
    fmi3LogMessageCallback log;
    fmi3ClockUpdateCallback clock_update;
} Instance;

static void logf_(Instance* c, fmi3Status status, const char* fmt, ...) {
    if (c->log == NULL) return;
    char buf[512];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    c->log(c->env, status, status >= fmi3Error ? "logStatusError" : "logEvents", buf);
}

#define INST Instance* c = (Instance*)instance; \
    if (c == NULL) return fmi3Error
#define REQUIRE(cond, ...) do { if (!(cond)) { logf_(c, fmi3Error, __VA_ARGS__); return fmi3Error; } } while (0)

static void set_start_values(State* s) {
    memset(s, 0, sizeof *s);
    s->mode = INSTANTIATED;
    s->gain = 2.0;
    s->period = 0.4;
    s->tunable_period = 0.5;
    s->fixed_interval = 0.25;
    s->r = 1.0;
    s->alarm_time = 1.737;
    s->t_alarm = -1.0;
    s->announce_alarm = 1.0;
}

static fmi3Instance instantiate(fmi3String name, fmi3String token, fmi3InstanceEnvironment env,
                                fmi3LogMessageCallback log, bool scheduled, fmi3ClockUpdateCallback update) {
    Instance* c = calloc(1, sizeof *c);
    if (c == NULL) return NULL;
    c->env = env;
    c->log = log;
    c->scheduled = scheduled;
    c->clock_update = update;
    (void)name;
    if (token == NULL || strcmp(token, CLOCKS3_TOKEN) != 0) {
        logf_(c, fmi3Error, "instantiation token %s does not match %s", token ? token : "(null)", CLOCKS3_TOKEN);
        free(c);
        return NULL;
    }
    set_start_values(&c->s);
    return c;
}

/* --- the model ----------------------------------------------------------------------------- */
static void integrate_to(State* s, double t) {
    double dt = t - s->time;
    if (dt > 0) s->x = s->u + (s->x - s->u) * exp(-dt);
    s->time = t;
}

static void run_partition(Instance* c, int clock) {
    State* s = &c->s;
    s->n[clock]++;
    s->t_last[clock] = s->time;
    switch (clock) {
        case C_CTRL: s->u = s->gain * (s->r - s->x); break;
        case C_CONST:
            s->countdown_interval = 0.05;
            s->countdown_qualifier = fmi3IntervalChanged;
            if (s->n[C_CONST] % 2 == 0) {
                s->out_clock = true;
                s->n[C_OUT]++;
            }
            break;
        case C_CHANGING:
            s->changing_count++;
            s->changing_interval = 0.1 * (s->changing_count + 1);
            s->changing_qualifier = fmi3IntervalChanged;
            break;
        case C_COUNTDOWN:
            if (s->countdown_qualifier != fmi3IntervalChanged) s->countdown_qualifier = fmi3IntervalNotYetKnown;
            break;
        default: break;
    }
}

static bool is_input_clock(fmi3ValueReference vr) { return vr >= C_CTRL && vr <= C_TRIGGER; }

/* --- life cycle ---------------------------------------------------------------------------- */
const char* fmi3GetVersion(void) { return fmi3Version; }

fmi3Status fmi3SetDebugLogging(fmi3Instance instance, fmi3Boolean loggingOn, size_t nCategories,
                               const fmi3String categories[]) {
    INST;
    (void)loggingOn; (void)nCategories; (void)categories;
    return fmi3OK;
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage) {
    (void)resourcePath; (void)visible; (void)loggingOn;
    return instantiate(instanceName, instantiationToken, instanceEnvironment, logMessage, false, NULL);
}

fmi3Instance fmi3InstantiateCoSimulation(fmi3String instanceName, fmi3String instantiationToken,
                                         fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                         fmi3Boolean eventModeUsed, fmi3Boolean earlyReturnAllowed,
                                         const fmi3ValueReference requiredIntermediateVariables[],
                                         size_t nRequiredIntermediateVariables,
                                         fmi3InstanceEnvironment instanceEnvironment,
                                         fmi3LogMessageCallback logMessage,
                                         fmi3IntermediateUpdateCallback intermediateUpdate) {
    (void)resourcePath; (void)visible; (void)loggingOn; (void)earlyReturnAllowed;
    (void)requiredIntermediateVariables; (void)nRequiredIntermediateVariables; (void)intermediateUpdate;
    if (!eventModeUsed) {
        if (logMessage != NULL)
            logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                       "clocks3 needs eventModeUsed = true: its clocks tick in event mode");
        return NULL;
    }
    return instantiate(instanceName, instantiationToken, instanceEnvironment, logMessage, false, NULL);
}

fmi3Instance fmi3InstantiateScheduledExecution(fmi3String instanceName, fmi3String instantiationToken,
                                               fmi3String resourcePath, fmi3Boolean visible,
                                               fmi3Boolean loggingOn, fmi3InstanceEnvironment instanceEnvironment,
                                               fmi3LogMessageCallback logMessage, fmi3ClockUpdateCallback clockUpdate,
                                               fmi3LockPreemptionCallback lockPreemption,
                                               fmi3UnlockPreemptionCallback unlockPreemption) {
    (void)resourcePath; (void)visible; (void)loggingOn; (void)lockPreemption; (void)unlockPreemption;
    if (clockUpdate == NULL) {
        if (logMessage != NULL)
            logMessage(instanceEnvironment, fmi3Error, "logStatusError", "clockUpdate must not be NULL");
        return NULL;
    }
    return instantiate(instanceName, instantiationToken, instanceEnvironment, logMessage, true, clockUpdate);
}

void fmi3FreeInstance(fmi3Instance instance) {
    Instance* c = (Instance*)instance;
    if (c == NULL) return;
    free(c);
}

fmi3Status fmi3EnterInitializationMode(fmi3Instance instance, fmi3Boolean toleranceDefined, fmi3Float64 tolerance,
                                       fmi3Float64 startTime, fmi3Boolean stopTimeDefined, fmi3Float64 stopTime) {
    INST;
    (void)toleranceDefined; (void)tolerance; (void)stopTimeDefined; (void)stopTime;
    REQUIRE(c->s.mode == INSTANTIATED, "fmi3EnterInitializationMode: not in the instantiated state");
    c->s.time = startTime;
    c->s.mode = INITIALIZATION;
    c->s.tunable_qualifier = fmi3IntervalChanged;
    c->s.changing_interval = 0.1;
    c->s.changing_qualifier = fmi3IntervalChanged;
    c->s.countdown_interval = 0.05;
    c->s.countdown_qualifier = fmi3IntervalChanged;
    return fmi3OK;
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance instance) {
    INST;
    REQUIRE(c->s.mode == INITIALIZATION, "fmi3ExitInitializationMode: not in initialization mode");
    REQUIRE(c->s.period > 0 && c->s.tunable_period > 0 && c->s.fixed_interval > 0,
            "period, tunable_period and the interval of c_fixed must be > 0");
    c->s.x = c->s.x0;
    /* the importer has read every interval in initialization mode: from now on they are known */
    c->s.tunable_qualifier = c->s.changing_qualifier = c->s.countdown_qualifier = fmi3IntervalUnchanged;
    c->s.mode = c->scheduled ? CLOCK_ACTIVATION : EVENT;
    c->s.evaluated = false;
    return fmi3OK;
}

fmi3Status fmi3EnterEventMode(fmi3Instance instance) {
    INST;
    REQUIRE(c->s.mode == STEP || c->s.mode == CONTINUOUS, "fmi3EnterEventMode: only from step or continuous-time mode");
    c->s.mode = EVENT;
    c->s.evaluated = false;
    return fmi3OK;
}

fmi3Status fmi3EnterStepMode(fmi3Instance instance) {
    INST;
    REQUIRE(c->s.mode == EVENT, "fmi3EnterStepMode: only from event mode");
    c->s.mode = STEP;
    memset(c->s.active, 0, sizeof c->s.active);
    c->s.out_clock = false;
    return fmi3OK;
}

fmi3Status fmi3Terminate(fmi3Instance instance) {
    INST;
    c->s.mode = TERMINATED;
    return fmi3OK;
}

fmi3Status fmi3Reset(fmi3Instance instance) {
    INST;
    set_start_values(&c->s);
    return fmi3OK;
}

/* --- variables ----------------------------------------------------------------------------- */
static double* float_ref(State* s, fmi3ValueReference vr) {
    switch (vr) {
        case VR_TIME: return &s->time;
        case VR_X: return &s->x;
        case VR_U: return &s->u;
        case VR_R: return &s->r;
        case VR_GAIN: return &s->gain;
        case VR_X0: return &s->x0;
        case VR_PERIOD: return &s->period;
        case VR_TUNABLE_PERIOD: return &s->tunable_period;
        case VR_ALARM_TIME: return &s->alarm_time;
        case VR_T_ALARM: return &s->t_alarm;
        case VR_ANNOUNCE_ALARM: return &s->announce_alarm;
        case VR_DER_X: return NULL; /* computed: see fmi3GetFloat64 */
        default:
            if (vr >= VR_T_FIRST && vr < VR_T_FIRST + N_INPUT_CLOCKS) return &s->t_last[vr - VR_T_FIRST + 1];
            return NULL;
    }
}

/* FMI 3.0: a clocked variable is read only while its clock is active (or in initialization mode);
 * this model refuses other reads, as a strict FMU may. */
static int clock_of(fmi3ValueReference vr) {
    if (vr == VR_U) return C_CTRL;
    if (vr >= VR_N_FIRST && vr < VR_N_FIRST + N_INPUT_CLOCKS) return (int)(vr - VR_N_FIRST) + 1;
    if (vr == VR_N_FIRST + N_INPUT_CLOCKS) return C_OUT;
    if (vr >= VR_T_FIRST && vr < VR_T_FIRST + N_INPUT_CLOCKS) return (int)(vr - VR_T_FIRST) + 1;
    return 0;
}

static bool readable(const Instance* c, fmi3ValueReference vr) {
    int clock = clock_of(vr);
    const State* s = &c->s;
    if (clock == 0 || s->mode == INSTANTIATED || s->mode == INITIALIZATION) return true;
    if (s->mode == EVENT) return clock == C_OUT ? s->out_clock : s->active[clock];
    if (s->mode == CLOCK_ACTIVATION) return clock == C_OUT ? s->last_partition == C_CONST : s->last_partition == clock;
    return false;
}

fmi3Status fmi3GetFloat64(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, fmi3Float64 values[],
                          size_t nValues) {
    INST;
    REQUIRE(nValues == nvr, "fmi3GetFloat64: nValues %zu != nValueReferences %zu", nValues, nvr);
    for (size_t k = 0; k < nvr; k++) {
        if (vr[k] == VR_DER_X) {
            values[k] = -c->s.x + c->s.u;
            continue;
        }
        double* p = float_ref(&c->s, vr[k]);
        REQUIRE(p != NULL, "fmi3GetFloat64: %u is not a Float64 variable", vr[k]);
        REQUIRE(readable(c, vr[k]), "fmi3GetFloat64: %u is a clocked variable and its clock is not active", vr[k]);
        values[k] = *p;
    }
    return fmi3OK;
}

fmi3Status fmi3SetFloat64(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                          const fmi3Float64 values[], size_t nValues) {
    INST;
    REQUIRE(nValues == nvr, "fmi3SetFloat64: nValues %zu != nValueReferences %zu", nValues, nvr);
    State* s = &c->s;
    bool init = s->mode == INSTANTIATED || s->mode == INITIALIZATION;
    for (size_t k = 0; k < nvr; k++) {
        fmi3ValueReference v = vr[k];
        if (v == VR_R) {
            s->r = values[k];
        } else if (v == VR_TUNABLE_PERIOD && (init || s->mode == EVENT || s->mode == CLOCK_ACTIVATION)) {
            REQUIRE(values[k] > 0, "tunable_period must be > 0, got %g", values[k]);
            if (values[k] != s->tunable_period) s->tunable_qualifier = fmi3IntervalChanged;
            s->tunable_period = values[k];
        } else if ((v == VR_GAIN || v == VR_X0 || v == VR_PERIOD || v == VR_ALARM_TIME || v == VR_ANNOUNCE_ALARM) && init) {
            *float_ref(s, v) = values[k];
        } else {
            REQUIRE(false, "fmi3SetFloat64: %u cannot be set now (mode %d)", v, (int)s->mode);
        }
    }
    return fmi3OK;
}

fmi3Status fmi3GetInt32(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, fmi3Int32 values[],
                        size_t nValues) {
    INST;
    REQUIRE(nValues == nvr, "fmi3GetInt32: nValues %zu != nValueReferences %zu", nValues, nvr);
    for (size_t k = 0; k < nvr; k++) {
        REQUIRE(vr[k] >= VR_N_FIRST && vr[k] <= VR_N_FIRST + N_INPUT_CLOCKS, "fmi3GetInt32: %u is not an Int32",
                vr[k]);
        REQUIRE(readable(c, vr[k]), "fmi3GetInt32: %u is a clocked variable and its clock is not active", vr[k]);
        values[k] = c->s.n[vr[k] - VR_N_FIRST + 1];
    }
    return fmi3OK;
}

fmi3Status fmi3GetClock(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, fmi3Clock values[]) {
    INST;
    for (size_t k = 0; k < nvr; k++) {
        if (vr[k] == C_OUT) {
            values[k] = c->s.out_clock;
            if (c->scheduled) c->s.out_clock = false; /* read once in clock update mode */
        } else {
            REQUIRE(is_input_clock(vr[k]), "fmi3GetClock: %u is not a clock", vr[k]);
            values[k] = c->s.active[vr[k]];
        }
    }
    return fmi3OK;
}

fmi3Status fmi3SetClock(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                        const fmi3Clock values[]) {
    INST;
    REQUIRE(c->s.mode == EVENT, "fmi3SetClock: only in event mode");
    for (size_t k = 0; k < nvr; k++) {
        REQUIRE(is_input_clock(vr[k]), "fmi3SetClock: %u is not an input clock", vr[k]);
        c->s.active[vr[k]] = values[k];
    }
    return fmi3OK;
}

fmi3Status fmi3UpdateDiscreteStates(fmi3Instance instance, fmi3Boolean* discreteStatesNeedUpdate,
                                    fmi3Boolean* terminateSimulation, fmi3Boolean* nominalsOfContinuousStatesChanged,
                                    fmi3Boolean* valuesOfContinuousStatesChanged, fmi3Boolean* nextEventTimeDefined,
                                    fmi3Float64* nextEventTime) {
    INST;
    REQUIRE(c->s.mode == EVENT, "fmi3UpdateDiscreteStates: only in event mode");
    if (!c->s.evaluated) { /* each active clock's partition runs once per event, in priority order */
        for (int clock = C_CTRL; clock <= C_TRIGGER; clock++)
            if (c->s.active[clock]) run_partition(c, clock);
        c->s.evaluated = true;
    }
    if (!c->s.alarm_fired && c->s.time >= c->s.alarm_time - 1e-12) { /* the FMU's own time event */
        c->s.alarm_fired = true;
        c->s.t_alarm = c->s.time;
    }
    *discreteStatesNeedUpdate = false;
    *terminateSimulation = false;
    *nominalsOfContinuousStatesChanged = false;
    *valuesOfContinuousStatesChanged = false;
    *nextEventTimeDefined = !c->s.alarm_fired && c->s.announce_alarm != 0.0;
    *nextEventTime = c->s.alarm_fired ? 0.0 : c->s.alarm_time;
    return fmi3OK;
}

/* --- intervals and shifts ------------------------------------------------------------------ */
static fmi3Status interval_of(Instance* c, fmi3ValueReference vr, double* interval, fmi3IntervalQualifier* q) {
    State* s = &c->s;
    bool init = s->mode == INITIALIZATION;
    switch (vr) {
        case C_CTRL: *interval = 0.1; *q = fmi3IntervalUnchanged; return fmi3OK;
        case C_CONST: *interval = 0.3; *q = fmi3IntervalUnchanged; return fmi3OK;
        case C_FIXED: *interval = s->fixed_interval; *q = fmi3IntervalUnchanged; return fmi3OK;
        case C_CALC: *interval = s->period; *q = init ? fmi3IntervalChanged : fmi3IntervalUnchanged; return fmi3OK;
        case C_TUNABLE:
            *interval = s->tunable_period;
            *q = (fmi3IntervalQualifier)s->tunable_qualifier;
            if (!init) s->tunable_qualifier = fmi3IntervalUnchanged;
            return fmi3OK;
        case C_CHANGING:
            *interval = s->changing_interval;
            *q = (fmi3IntervalQualifier)s->changing_qualifier;
            if (!init) s->changing_qualifier = fmi3IntervalUnchanged;
            return fmi3OK;
        case C_COUNTDOWN:
            *interval = s->countdown_interval;
            *q = (fmi3IntervalQualifier)s->countdown_qualifier;
            if (!init && s->countdown_qualifier == fmi3IntervalChanged) s->countdown_qualifier = fmi3IntervalUnchanged;
            return fmi3OK;
        default: logf_(c, fmi3Error, "fmi3GetIntervalDecimal: %u is not a time-based clock", vr); return fmi3Error;
    }
}

fmi3Status fmi3GetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                  fmi3Float64 intervals[], fmi3IntervalQualifier qualifiers[]) {
    INST;
    for (size_t k = 0; k < nvr; k++)
        if (interval_of(c, vr[k], &intervals[k], &qualifiers[k]) != fmi3OK) return fmi3Error;
    return fmi3OK;
}

fmi3Status fmi3GetShiftDecimal(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                               fmi3Float64 shifts[]) {
    INST;
    for (size_t k = 0; k < nvr; k++) {
        switch (vr[k]) {
            case C_CTRL: shifts[k] = 0.0; break;
            case C_CONST: shifts[k] = 0.1; break;
            case C_FIXED: shifts[k] = 0.05; break;
            case C_CALC: shifts[k] = c->s.period / 2; break;
            case C_TUNABLE: shifts[k] = 0.0; break;
            default: REQUIRE(false, "fmi3GetShiftDecimal: %u is not a periodic clock", vr[k]);
        }
    }
    return fmi3OK;
}

fmi3Status fmi3SetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                  const fmi3Float64 intervals[]) {
    INST;
    for (size_t k = 0; k < nvr; k++) {
        REQUIRE(vr[k] == C_FIXED && c->s.mode == INITIALIZATION,
                "fmi3SetIntervalDecimal: only c_fixed's interval, in initialization mode (%u)", vr[k]);
        REQUIRE(intervals[k] > 0, "fmi3SetIntervalDecimal: the interval must be > 0, got %g", intervals[k]);
        c->s.fixed_interval = intervals[k];
    }
    return fmi3OK;
}

/* --- co-simulation ------------------------------------------------------------------------- */
fmi3Status fmi3DoStep(fmi3Instance instance, fmi3Float64 currentCommunicationPoint,
                      fmi3Float64 communicationStepSize, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                      fmi3Boolean* eventHandlingNeeded, fmi3Boolean* terminateSimulation, fmi3Boolean* earlyReturn,
                      fmi3Float64* lastSuccessfulTime) {
    INST;
    (void)noSetFMUStatePriorToCurrentPoint;
    REQUIRE(c->s.mode == STEP, "fmi3DoStep: only in step mode");
    REQUIRE(fabs(currentCommunicationPoint - c->s.time) <= 1e-9 * fmax(1.0, fabs(c->s.time)),
            "fmi3DoStep: currentCommunicationPoint %.17g is not the FMU's time %.17g", currentCommunicationPoint,
            c->s.time);
    REQUIRE(communicationStepSize > 0, "fmi3DoStep: step size %g <= 0", communicationStepSize);
    integrate_to(&c->s, currentCommunicationPoint + communicationStepSize);
    *eventHandlingNeeded = !c->s.alarm_fired && c->s.time >= c->s.alarm_time - 1e-12; /* passed it */
    *terminateSimulation = false;
    *earlyReturn = false;
    *lastSuccessfulTime = c->s.time;
    return fmi3OK;
}

/* --- scheduled execution ------------------------------------------------------------------- */
fmi3Status fmi3ActivateModelPartition(fmi3Instance instance, fmi3ValueReference clockReference,
                                      fmi3Float64 activationTime) {
    INST;
    REQUIRE(c->scheduled && c->s.mode == CLOCK_ACTIVATION, "fmi3ActivateModelPartition: not in clock activation mode");
    REQUIRE(is_input_clock(clockReference), "fmi3ActivateModelPartition: %u is not an input clock", clockReference);
    REQUIRE(activationTime >= c->s.time - 1e-12, "fmi3ActivateModelPartition: time %.17g is before %.17g",
            activationTime, c->s.time);
    integrate_to(&c->s, activationTime);
    c->s.active[clockReference] = true;
    c->s.last_partition = (int)clockReference;
    run_partition(c, (int)clockReference);
    c->s.active[clockReference] = false;
    bool update = c->s.out_clock || (clockReference == C_CONST) || (clockReference == C_CHANGING) ||
                  c->s.tunable_qualifier == fmi3IntervalChanged;
    if (update) c->clock_update(c->env);
    return fmi3OK;
}

/* --- model exchange: the importer integrates x' = -x + u -------------------------------------- */
fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance instance) {
    INST;
    REQUIRE(c->s.mode == EVENT, "fmi3EnterContinuousTimeMode: only from event mode");
    c->s.mode = CONTINUOUS;
    memset(c->s.active, 0, sizeof c->s.active);
    c->s.out_clock = false;
    return fmi3OK;
}

fmi3Status fmi3CompletedIntegratorStep(fmi3Instance instance, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean* enterEventMode, fmi3Boolean* terminateSimulation) {
    INST;
    (void)noSetFMUStatePriorToCurrentPoint;
    *enterEventMode = false;
    *terminateSimulation = false;
    return fmi3OK;
}

fmi3Status fmi3SetTime(fmi3Instance instance, fmi3Float64 time) {
    INST;
    c->s.time = time;
    return fmi3OK;
}

fmi3Status fmi3SetContinuousStates(fmi3Instance instance, const fmi3Float64 continuousStates[],
                                   size_t nContinuousStates) {
    INST;
    REQUIRE(nContinuousStates == 1, "fmi3SetContinuousStates: 1 state, got %zu", nContinuousStates);
    c->s.x = continuousStates[0];
    return fmi3OK;
}

fmi3Status fmi3GetContinuousStates(fmi3Instance instance, fmi3Float64 continuousStates[], size_t nContinuousStates) {
    INST;
    REQUIRE(nContinuousStates == 1, "fmi3GetContinuousStates: 1 state, got %zu", nContinuousStates);
    continuousStates[0] = c->s.x;
    return fmi3OK;
}

fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance instance, fmi3Float64 derivatives[],
                                             size_t nContinuousStates) {
    INST;
    REQUIRE(nContinuousStates == 1, "fmi3GetContinuousStateDerivatives: 1 state, got %zu", nContinuousStates);
    derivatives[0] = -c->s.x + c->s.u;
    return fmi3OK;
}

fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance instance, fmi3Float64 nominals[],
                                             size_t nContinuousStates) {
    INST;
    for (size_t k = 0; k < nContinuousStates; k++) nominals[k] = 1.0;
    return fmi3OK;
}

fmi3Status fmi3GetEventIndicators(fmi3Instance instance, fmi3Float64 eventIndicators[], size_t nEventIndicators) {
    INST;
    (void)eventIndicators;
    REQUIRE(nEventIndicators == 0, "fmi3GetEventIndicators: no event indicators, got %zu", nEventIndicators);
    return fmi3OK;
}

fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance instance, size_t* nEventIndicators) {
    INST;
    *nEventIndicators = 0;
    return fmi3OK;
}

fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance instance, size_t* nContinuousStates) {
    INST;
    *nContinuousStates = 1;
    return fmi3OK;
}

/* --- FMU state (a copy of the State struct) ------------------------------------------------ */
fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState* FMUState) {
    INST;
    if (*FMUState == NULL) *FMUState = malloc(sizeof(State));
    REQUIRE(*FMUState != NULL, "fmi3GetFMUState: out of memory");
    memcpy(*FMUState, &c->s, sizeof(State));
    return fmi3OK;
}

fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState FMUState) {
    INST;
    REQUIRE(FMUState != NULL, "fmi3SetFMUState: NULL state");
    memcpy(&c->s, FMUState, sizeof(State));
    return fmi3OK;
}

fmi3Status fmi3FreeFMUState(fmi3Instance instance, fmi3FMUState* FMUState) {
    INST;
    free(*FMUState);
    *FMUState = NULL;
    return fmi3OK;
}

/* --- everything else: declared false or absent in modelDescription.xml --------------------- */
#define REFUSED(NAME, PARAMS)                                                              \
    fmi3Status NAME PARAMS {                                                               \
        INST;                                                                              \
        logf_(c, fmi3Error, "%s is not supported by clocks3", #NAME);                      \
        return fmi3Error;                                                                  \
    }

#define REFUSED_GET(NAME, T) REFUSED(NAME, (fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, \
                                             T values[], size_t nValues))
#define REFUSED_SET(NAME, T) REFUSED(NAME, (fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, \
                                             const T values[], size_t nValues))
REFUSED_GET(fmi3GetFloat32, fmi3Float32)
REFUSED_GET(fmi3GetInt8, fmi3Int8)
REFUSED_GET(fmi3GetUInt8, fmi3UInt8)
REFUSED_GET(fmi3GetInt16, fmi3Int16)
REFUSED_GET(fmi3GetUInt16, fmi3UInt16)
REFUSED_GET(fmi3GetUInt32, fmi3UInt32)
REFUSED_GET(fmi3GetInt64, fmi3Int64)
REFUSED_GET(fmi3GetUInt64, fmi3UInt64)
REFUSED_GET(fmi3GetBoolean, fmi3Boolean)
REFUSED_GET(fmi3GetString, fmi3String)
REFUSED_SET(fmi3SetFloat32, fmi3Float32)
REFUSED_SET(fmi3SetInt8, fmi3Int8)
REFUSED_SET(fmi3SetUInt8, fmi3UInt8)
REFUSED_SET(fmi3SetInt16, fmi3Int16)
REFUSED_SET(fmi3SetUInt16, fmi3UInt16)
REFUSED_SET(fmi3SetInt32, fmi3Int32)
REFUSED_SET(fmi3SetUInt32, fmi3UInt32)
REFUSED_SET(fmi3SetInt64, fmi3Int64)
REFUSED_SET(fmi3SetUInt64, fmi3UInt64)
REFUSED_SET(fmi3SetBoolean, fmi3Boolean)
REFUSED_SET(fmi3SetString, fmi3String)
REFUSED(fmi3GetBinary, (fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, size_t valueSizes[],
                        fmi3Binary values[], size_t nValues))
REFUSED(fmi3SetBinary, (fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                        const size_t valueSizes[], const fmi3Binary values[], size_t nValues))
REFUSED(fmi3GetNumberOfVariableDependencies, (fmi3Instance instance, fmi3ValueReference valueReference,
                                              size_t* nDependencies))
REFUSED(fmi3GetVariableDependencies, (fmi3Instance instance, fmi3ValueReference dependent,
                                      size_t elementIndicesOfDependent[], fmi3ValueReference independents[],
                                      size_t elementIndicesOfIndependents[], fmi3DependencyKind dependencyKinds[],
                                      size_t nDependencies))
REFUSED(fmi3SerializedFMUStateSize, (fmi3Instance instance, fmi3FMUState FMUState, size_t* size))
REFUSED(fmi3SerializeFMUState, (fmi3Instance instance, fmi3FMUState FMUState, fmi3Byte serializedState[],
                                size_t size))
REFUSED(fmi3DeserializeFMUState, (fmi3Instance instance, const fmi3Byte serializedState[], size_t size,
                                  fmi3FMUState* FMUState))
REFUSED(fmi3GetDirectionalDerivative, (fmi3Instance instance, const fmi3ValueReference unknowns[],
                                       size_t nUnknowns, const fmi3ValueReference knowns[], size_t nKnowns,
                                       const fmi3Float64 seed[], size_t nSeed, fmi3Float64 sensitivity[],
                                       size_t nSensitivity))
REFUSED(fmi3GetAdjointDerivative, (fmi3Instance instance, const fmi3ValueReference unknowns[], size_t nUnknowns,
                                   const fmi3ValueReference knowns[], size_t nKnowns, const fmi3Float64 seed[],
                                   size_t nSeed, fmi3Float64 sensitivity[], size_t nSensitivity))
REFUSED(fmi3EnterConfigurationMode, (fmi3Instance instance))
REFUSED(fmi3ExitConfigurationMode, (fmi3Instance instance))
REFUSED(fmi3GetIntervalFraction, (fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                  fmi3UInt64 counters[], fmi3UInt64 resolutions[],
                                  fmi3IntervalQualifier qualifiers[]))
REFUSED(fmi3GetShiftFraction, (fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                               fmi3UInt64 counters[], fmi3UInt64 resolutions[]))
REFUSED(fmi3SetIntervalFraction, (fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                  const fmi3UInt64 counters[], const fmi3UInt64 resolutions[]))
REFUSED(fmi3SetShiftDecimal, (fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                              const fmi3Float64 shifts[]))
REFUSED(fmi3SetShiftFraction, (fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                               const fmi3UInt64 counters[], const fmi3UInt64 resolutions[]))
REFUSED(fmi3EvaluateDiscreteStates, (fmi3Instance instance))
REFUSED(fmi3GetOutputDerivatives, (fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                   const fmi3Int32 orders[], fmi3Float64 values[], size_t nValues))
