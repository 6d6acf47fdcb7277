/* strict_reset: an FMI 2.0 co-simulation model whose reset and state functions misbehave the
 * way some real exporters' do (both legal readings of a loose spot of the standard, or common bugs),
 * written without the shared framework of models/common.
 *
 *   u        Real input, 0 until set
 *   k        Real tunable parameter: the decay rate (1)
 *   t_end    Real fixed parameter: the model asks to terminate at this time (1 s)
 *   quirks   Integer fixed parameter, a bit set (3):
 *              1  fmi2Reset keeps the terminated flag: after a run to t_end, every doStep after a
 *                 reset is answered fmi2Discard with fmi2Terminated true
 *              2  fmi2GetFMUstate and fmi2SetFMUstate answer fmi2Error on an instance that was
 *                 reset (fmi2Reset) since it was instantiated
 *   x        Real output: dx/dt = u - k x, x(0) = 1, stepped with its closed form (u held)
 *
 * doStep ends at t >= t_end - 1e-9 h with fmi2Discard and fmi2Terminated true (the step itself is
 * taken). Anything called in the wrong state is answered fmi2Error with a log message. */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"

#define VR_U 0
#define VR_K 1
#define VR_T_END 2
#define VR_X 3
#define VR_QUIRKS 4
#define KEEPS_TERMINATED 1
#define STATE_REFUSED_AFTER_RESET 2
#define UNUSED(x) (void)(x)

typedef struct {
    double time, u, k, t_end, x;
    int quirks, terminated, initialized;
} State;

typedef struct {
    State s;
    int was_reset;
    fmi2CallbackFunctions cb;
    fmi2String name;
} Instance;

static fmi2Status fail(Instance* m, const char* format, ...) {
    char text[512];
    va_list args;
    va_start(args, format);
    vsnprintf(text, sizeof text, format, args);
    va_end(args);
    if (m->cb.logger != NULL) m->cb.logger(m->cb.componentEnvironment, m->name, fmi2Error, "logStatusError", text);
    return fmi2Error;
}

static void start_values(State* s) {
    s->time = 0.0;
    s->u = 0.0;
    s->k = 1.0;
    s->t_end = 1.0;
    s->x = 1.0;
    s->quirks = KEEPS_TERMINATED | STATE_REFUSED_AFTER_RESET;
    s->initialized = 0;
}

FMI2_Export const char* fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
FMI2_Export const char* fmi2GetVersion(void) { return fmi2Version; }
FMI2_Export fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String cats[]) {
    UNUSED(c); UNUSED(on); UNUSED(n); UNUSED(cats);
    return fmi2OK;
}

FMI2_Export fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid, fmi2String location,
                                          const fmi2CallbackFunctions* cb, fmi2Boolean visible, fmi2Boolean log) {
    UNUSED(guid); UNUSED(location); UNUSED(visible); UNUSED(log);
    if (type != fmi2CoSimulation || cb == NULL) return NULL;
    Instance* m = calloc(1, sizeof *m);
    if (m == NULL) return NULL;
    m->cb = *cb;
    m->name = name;
    start_values(&m->s);
    return m;
}

FMI2_Export void fmi2FreeInstance(fmi2Component c) { free(c); }

FMI2_Export fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean tol_defined, fmi2Real tol, fmi2Real start,
                                           fmi2Boolean stop_defined, fmi2Real stop) {
    UNUSED(tol_defined); UNUSED(tol); UNUSED(stop_defined); UNUSED(stop);
    ((Instance*)c)->s.time = start;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2EnterInitializationMode(fmi2Component c) { UNUSED(c); return fmi2OK; }

FMI2_Export fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    ((Instance*)c)->s.initialized = 1;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2Terminate(fmi2Component c) { UNUSED(c); return fmi2OK; }

FMI2_Export fmi2Status fmi2Reset(fmi2Component c) {
    Instance* m = c;
    int kept = (m->s.quirks & KEEPS_TERMINATED) ? m->s.terminated : 0;
    start_values(&m->s);
    m->s.terminated = kept;  /* the quirk: a finished run stays finished */
    m->was_reset = 1;
    return fmi2OK;
}

static double* real_at(Instance* m, fmi2ValueReference vr) {
    switch (vr) {
        case VR_U: return &m->s.u;
        case VR_K: return &m->s.k;
        case VR_T_END: return &m->s.t_end;
        case VR_X: return &m->s.x;
        default: return NULL;
    }
}

FMI2_Export fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real v[]) {
    Instance* m = c;
    for (size_t i = 0; i < n; i++) {
        double* p = real_at(m, vr[i]);
        if (p == NULL) return fail(m, "fmi2GetReal: value reference %u is not a Real", (unsigned)vr[i]);
        v[i] = *p;
    }
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real v[]) {
    Instance* m = c;
    for (size_t i = 0; i < n; i++) {
        double* p = real_at(m, vr[i]);
        if (p == NULL || vr[i] == VR_X) return fail(m, "fmi2SetReal: value reference %u cannot be set", (unsigned)vr[i]);
        if (vr[i] == VR_T_END && m->s.initialized) return fail(m, "fmi2SetReal: t_end is fixed after initialisation");
        *p = v[i];
    }
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Integer v[]) {
    Instance* m = c;
    for (size_t i = 0; i < n; i++) {
        if (vr[i] != VR_QUIRKS) return fail(m, "fmi2GetInteger: value reference %u is not an Integer", (unsigned)vr[i]);
        v[i] = m->s.quirks;
    }
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer v[]) {
    Instance* m = c;
    for (size_t i = 0; i < n; i++) {
        if (vr[i] != VR_QUIRKS || m->s.initialized) return fail(m, "fmi2SetInteger: value reference %u cannot be set now", (unsigned)vr[i]);
        m->s.quirks = v[i];
    }
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Boolean v[]) {
    UNUSED(v);
    return n == 0 ? fmi2OK : fail(c, "fmi2GetBoolean: value reference %u is not a Boolean", (unsigned)vr[0]);
}
FMI2_Export fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Boolean v[]) {
    UNUSED(v);
    return n == 0 ? fmi2OK : fail(c, "fmi2SetBoolean: value reference %u is not a Boolean", (unsigned)vr[0]);
}
FMI2_Export fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2String v[]) {
    UNUSED(v);
    return n == 0 ? fmi2OK : fail(c, "fmi2GetString: value reference %u is not a String", (unsigned)vr[0]);
}
FMI2_Export fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2String v[]) {
    UNUSED(v);
    return n == 0 ? fmi2OK : fail(c, "fmi2SetString: value reference %u is not a String", (unsigned)vr[0]);
}

static fmi2Status refuse_after_reset(Instance* m, const char* fn) {
    return fail(m, "%s: this instance was reset; its state cannot be read or written", fn);
}

FMI2_Export fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate* state) {
    Instance* m = c;
    if ((m->s.quirks & STATE_REFUSED_AFTER_RESET) && m->was_reset) return refuse_after_reset(m, "fmi2GetFMUstate");
    State* copy = *state != NULL ? *state : malloc(sizeof *copy);
    if (copy == NULL) return fail(m, "fmi2GetFMUstate: out of memory");
    *copy = m->s;
    *state = copy;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate state) {
    Instance* m = c;
    if ((m->s.quirks & STATE_REFUSED_AFTER_RESET) && m->was_reset) return refuse_after_reset(m, "fmi2SetFMUstate");
    if (state == NULL) return fail(m, "fmi2SetFMUstate: no state");
    m->s = *(State*)state;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate* state) {
    UNUSED(c);
    if (state != NULL) {
        free(*state);
        *state = NULL;
    }
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate s, size_t* n) {
    UNUSED(s); UNUSED(n);
    return fail(c, "fmi2SerializedFMUstateSize: not supported");
}
FMI2_Export fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate s, fmi2Byte b[], size_t n) {
    UNUSED(s); UNUSED(b); UNUSED(n);
    return fail(c, "fmi2SerializeFMUstate: not supported");
}
FMI2_Export fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte b[], size_t n, fmi2FMUstate* s) {
    UNUSED(b); UNUSED(n); UNUSED(s);
    return fail(c, "fmi2DeSerializeFMUstate: not supported");
}
FMI2_Export fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference a[], size_t na,
                                                    const fmi2ValueReference b[], size_t nb, const fmi2Real dv[],
                                                    fmi2Real out[]) {
    UNUSED(a); UNUSED(na); UNUSED(b); UNUSED(nb); UNUSED(dv); UNUSED(out);
    return fail(c, "fmi2GetDirectionalDerivative: not supported");
}
FMI2_Export fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                                   const fmi2Integer order[], const fmi2Real v[]) {
    UNUSED(vr); UNUSED(n); UNUSED(order); UNUSED(v);
    return fail(c, "fmi2SetRealInputDerivatives: not supported");
}
FMI2_Export fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                                    const fmi2Integer order[], fmi2Real v[]) {
    UNUSED(vr); UNUSED(n); UNUSED(order); UNUSED(v);
    return fail(c, "fmi2GetRealOutputDerivatives: not supported");
}

FMI2_Export fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean no_prior) {
    Instance* m = c;
    UNUSED(no_prior);
    if (!m->s.initialized) return fail(m, "fmi2DoStep: not initialised");
    if (m->s.terminated) return fmi2Discard;  /* asked to terminate before: nothing more to step */
    double target = m->s.u / m->s.k;
    m->s.x = target + (m->s.x - target) * exp(-m->s.k * h);
    m->s.time = t + h;
    if (m->s.time >= m->s.t_end - 1e-9 * h) {
        m->s.terminated = 1;
        return fmi2Discard;
    }
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2CancelStep(fmi2Component c) { return fail(c, "fmi2CancelStep: not supported"); }

FMI2_Export fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status* v) {
    UNUSED(s); UNUSED(v);
    return fail(c, "fmi2GetStatus: not supported");
}
FMI2_Export fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real* v) {
    Instance* m = c;
    if (s != fmi2LastSuccessfulTime) return fail(m, "fmi2GetRealStatus: only fmi2LastSuccessfulTime");
    *v = m->s.time;
    return fmi2OK;
}
FMI2_Export fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer* v) {
    UNUSED(s); UNUSED(v);
    return fail(c, "fmi2GetIntegerStatus: not supported");
}
FMI2_Export fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean* v) {
    Instance* m = c;
    if (s != fmi2Terminated) return fail(m, "fmi2GetBooleanStatus: only fmi2Terminated");
    *v = m->s.terminated ? fmi2True : fmi2False;
    return fmi2OK;
}
FMI2_Export fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String* v) {
    UNUSED(s); UNUSED(v);
    return fail(c, "fmi2GetStringStatus: not supported");
}
