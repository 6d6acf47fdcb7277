/* Fixed-step explicit integration of one model-exchange instance (FMI 2.0 / 3.0), in native code.
 *
 * `fixed_step_advance` integrates from call->time towards call->end with classic Runge-Kutta (RK4)
 * or forward Euler on the grid origin + j * substep (j = 1 .. total; the last point is `end`
 * exactly), calling the FMU's own functions: set time, set continuous states, get derivatives, get
 * event indicators, completed integrator step. It returns at the first of:
 *
 *   FS_END         the end was reached;
 *   FS_STATE_EVENT an event indicator changed sign during a substep: the crossing is located by
 *                  bisection over the substep's length (re-integrating from its start), the instance
 *                  is left just past it;
 *   FS_TIME_EVENT  the time event call->next_event (NaN: none) was reached;
 *   FS_STEP_EVENT  completedIntegratorStep asked for event mode;
 *   FS_TERMINATE   completedIntegratorStep asked to terminate;
 *   FS_FAILED + 16 * function + status: an FMI call returned Error or worse.
 *
 * The caller runs the event iteration and calls again from the new time. States are read from the
 * instance at every call, so resets, restored states and event re-initialisation need no restart.
 */
#include <math.h>
#include <pthread.h>
#include <stdbool.h>
#include <stddef.h>
#include <string.h>

#include "fmi2FunctionTypes.h"
#include "fmi3FunctionTypes.h"

#define FS_END 0
#define FS_STATE_EVENT 1
#define FS_TIME_EVENT 2
#define FS_STEP_EVENT 3
#define FS_TERMINATE 4
#define FS_FAILED 64
#define FS_BISECTIONS 60
#define WARNING 1

enum { F_SET_TIME, F_SET_X, F_GET_X, F_GET_DX, F_GET_Z, F_COMPLETED };

typedef struct {
    int major;             /* 2 or 3 */
    int method;            /* 0: Euler, 1: RK4 */
    int nx;                /* continuous states */
    int nz;                /* event indicators */
    int completed;         /* call completedIntegratorStep after each substep */
    void* set_time;        /* fmi2SetTime / fmi3SetTime */
    void* set_x;           /* fmi2SetContinuousStates / fmi3SetContinuousStates */
    void* get_x;           /* fmi2GetContinuousStates / fmi3GetContinuousStates */
    void* get_dx;          /* fmi2GetDerivatives / fmi3GetContinuousStateDerivatives */
    void* get_z;           /* fmi2GetEventIndicators / fmi3GetEventIndicators */
    void* completed_step;  /* fmi2CompletedIntegratorStep / fmi3CompletedIntegratorStep */
    double* work;          /* 7 * nx + 3 * nz doubles owned by the caller */
} FixedSpec;

typedef struct {
    void* component;
    double time;        /* in: where the instance is; out: where it stopped */
    double origin;      /* the sample's start: grid points are origin + j * substep */
    double substep;
    long long total;    /* grid points in the sample: end = origin + total * substep */
    double end;
    double next_event;  /* the time event this call stops at, NaN if none */
    double announced;   /* the time event the FMU announced, NaN if none (fixed_step_batch) */
} FixedCall;

typedef struct {
    const FixedSpec* s;
    void* c;
    double *x, *k, *xs, *xa, *za, *zb, *zt;
} Ctx;

#define TRY(call, fn)                          \
    do {                                       \
        int st_ = (call);                      \
        if (st_ > WARNING) return FS_FAILED + 16 * (fn) + st_; \
    } while (0)

static int set_time(const Ctx* c, double t) {
    return c->s->major == 3 ? ((fmi3SetTimeTYPE*)c->s->set_time)(c->c, t)
                            : ((fmi2SetTimeTYPE*)c->s->set_time)(c->c, t);
}

static int set_x(const Ctx* c, const double* x) {
    size_t n = (size_t)c->s->nx;
    return c->s->major == 3 ? ((fmi3SetContinuousStatesTYPE*)c->s->set_x)(c->c, x, n)
                            : ((fmi2SetContinuousStatesTYPE*)c->s->set_x)(c->c, x, n);
}

static int get_x(const Ctx* c, double* x) {
    size_t n = (size_t)c->s->nx;
    return c->s->major == 3 ? ((fmi3GetContinuousStatesTYPE*)c->s->get_x)(c->c, x, n)
                            : ((fmi2GetContinuousStatesTYPE*)c->s->get_x)(c->c, x, n);
}

static int get_z(const Ctx* c, double* z) {
    size_t n = (size_t)c->s->nz;
    if (n == 0) return 0;
    return c->s->major == 3 ? ((fmi3GetEventIndicatorsTYPE*)c->s->get_z)(c->c, z, n)
                            : ((fmi2GetEventIndicatorsTYPE*)c->s->get_z)(c->c, z, n);
}

/* dx = f(t, x): the instance is left at (t, x); `there`: it is there already (no set calls). */
static int rhs(const Ctx* c, double t, const double* x, double* dx, bool there) {
    size_t n = (size_t)c->s->nx;
    if (!there) TRY(set_time(c, t), F_SET_TIME);
    if (n == 0) return FS_END;
    if (!there) TRY(set_x(c, x), F_SET_X);
    TRY(c->s->major == 3 ? ((fmi3GetContinuousStateDerivativesTYPE*)c->s->get_dx)(c->c, dx, n)
                         : ((fmi2GetDerivativesTYPE*)c->s->get_dx)(c->c, dx, n),
        F_GET_DX);
    return FS_END;
}

/* out = one step from (t, x) to t_end; the instance is left at (t_end, out). `there`: the
 * instance is at (t, x) already (the end of the previous substep). */
static int step(const Ctx* c, double t, const double* x, double t_end, double* out, bool there) {
    int nx = c->s->nx, r;
    double h = t_end - t;
    double *k = c->k, *xs = c->xs;
    if ((r = rhs(c, t, x, k, there)) != FS_END) return r;
    if (c->s->method == 0) {
        for (int i = 0; i < nx; i++) out[i] = x[i] + h * k[i];
    } else {
        double *k2 = k + nx, *k3 = k + 2 * nx, *k4 = k + 3 * nx;
        for (int i = 0; i < nx; i++) xs[i] = x[i] + 0.5 * h * k[i];
        if ((r = rhs(c, t + 0.5 * h, xs, k2, false)) != FS_END) return r;
        for (int i = 0; i < nx; i++) xs[i] = x[i] + 0.5 * h * k2[i];
        if ((r = rhs(c, t + 0.5 * h, xs, k3, false)) != FS_END) return r;
        for (int i = 0; i < nx; i++) xs[i] = x[i] + h * k3[i];
        if ((r = rhs(c, t + h, xs, k4, false)) != FS_END) return r;
        for (int i = 0; i < nx; i++) out[i] = x[i] + h / 6.0 * (k[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
    }
    TRY(set_time(c, t_end), F_SET_TIME);
    if (nx > 0) TRY(set_x(c, out), F_SET_X);
    return FS_END;
}

/* An indicator crossed from a < 0 to b >= 0 or from a > 0 to b <= 0 (leaving zero is no event). */
static bool crossed(const double* a, const double* b, int nz) {
    for (int i = 0; i < nz; i++) {
        if ((a[i] > 0.0 && b[i] <= 0.0) || (a[i] < 0.0 && b[i] >= 0.0)) return true;
    }
    return false;
}

/* Bisect the substep from (t, xa) of length h whose end crossed: leave the instance at the
 * shortest length found after which an indicator has crossed. */
static int locate(const Ctx* c, double t, double h, double* stop) {
    double lo = 0.0, hi = h;
    int r;
    for (int i = 0; i < FS_BISECTIONS && hi - lo > 1e-13 * (fabs(t) + h); i++) {
        double mid = 0.5 * (lo + hi);
        if ((r = step(c, t, c->xa, t + mid, c->x, false)) != FS_END) return r;
        TRY(get_z(c, c->zt), F_GET_Z);
        if (crossed(c->za, c->zt, c->s->nz)) hi = mid;
        else lo = mid;
    }
    if ((r = step(c, t, c->xa, t + hi, c->x, false)) != FS_END) return r;
    *stop = t + hi;
    return FS_END;
}

static int completed(const Ctx* c) {
    if (!c->s->completed) return FS_END;
    if (c->s->major == 3) {
        fmi3Boolean event = fmi3False, stop = fmi3False;
        TRY(((fmi3CompletedIntegratorStepTYPE*)c->s->completed_step)(c->c, fmi3True, &event, &stop), F_COMPLETED);
        return stop ? FS_TERMINATE : event ? FS_STEP_EVENT : FS_END;
    }
    fmi2Boolean event = fmi2False, stop = fmi2False;
    TRY(((fmi2CompletedIntegratorStepTYPE*)c->s->completed_step)(c->c, fmi2True, &event, &stop), F_COMPLETED);
    return stop ? FS_TERMINATE : event ? FS_STEP_EVENT : FS_END;
}

/* The grid point after t: the first origin + j * substep more than a rounding error past t. */
static long long next_point(const FixedCall* call) {
    double j = floor((call->time - call->origin) / call->substep + 1e-9) + 1.0;
    return j > (double)call->total ? call->total : (long long)j;
}

int fixed_step_advance(const FixedSpec* s, FixedCall* call) {
    int nx = s->nx, nz = s->nz, r;
    double* w = s->work;
    Ctx c = {s, call->component, w, w + nx, w + 5 * nx, w + 6 * nx, w + 7 * nx, w + 7 * nx + nz,
             w + 7 * nx + 2 * nz};
    if (nx > 0) TRY(get_x(&c, c.xa), F_GET_X);
    TRY(get_z(&c, c.za), F_GET_Z);
    bool has_event = !isnan(call->next_event);
    bool there = false; /* the first substep of a call sets time and states itself */
    while (call->time < call->end) {
        long long j = next_point(call);
        double target = j == call->total ? call->end : call->origin + (double)j * call->substep;
        bool time_event = has_event && call->next_event <= target + 1e-12 * (fabs(target) + 1.0);
        if (time_event) target = call->next_event > call->time ? call->next_event : call->time;
        double t = call->time;
        if ((r = step(&c, t, c.xa, target, c.x, there)) != FS_END) return r;
        TRY(get_z(&c, c.zb), F_GET_Z);
        if (crossed(c.za, c.zb, nz)) {
            if ((r = locate(&c, t, target - t, &call->time)) != FS_END) return r;
            return (r = completed(&c)) != FS_END ? r : FS_STATE_EVENT;
        }
        call->time = target;
        if ((r = completed(&c)) != FS_END) return r;
        if (time_event) return FS_TIME_EVENT;
        memcpy(c.xa, c.x, sizeof(double) * (size_t)nx);
        there = true;
        memcpy(c.za, c.zb, sizeof(double) * (size_t)nz);
    }
    return FS_END;
}

/* ---- batches: one sample of many instances of one FMU in one call ---------------------------- */

#define FB_SET 16 /* + status: setting the inputs failed */
#define FB_GET 32 /* + status: getting the outputs failed */
#define FB_MAX_THREADS 64

typedef struct {
    int major;
    void* set_real;  /* fmi2SetReal / fmi3SetFloat64 */
    void* get_real;  /* fmi2GetReal / fmi3GetFloat64 */
    int n_in;
    const unsigned int* in_vr;
    int n_out;
    const unsigned int* out_vr;
    double t0;       /* start time */
    double h;        /* FMU step */
    int steps;       /* FMU steps per sample */
    int substeps;    /* integration steps per FMU step */
    int nv_in;       /* values of the inputs (FMI 3.0 arrays count every element): a row of inputs */
    int nv_out;      /* values of the outputs */
} FixedBatch;

static bool near(double a, double b) { /* Python's math.isclose(a, b, rel_tol=1e-12, abs_tol=1e-12) */
    double tol = 1e-12 * fmax(fabs(a), fabs(b));
    return fabs(a - b) <= fmax(tol, 1e-12);
}

/* One instance's sample (see fixed_step_batch). */
static int batch_one(const FixedBatch* b, const FixedSpec* spec, FixedCall* call, const double* u, double* y,
                     long long* k) {
    void* c = call->component;
    int st;
    if (b->n_in > 0) {
        st = b->major == 3 ? ((fmi3SetFloat64TYPE*)b->set_real)(c, b->in_vr, b->n_in, u, b->nv_in)
                           : ((fmi2SetRealTYPE*)b->set_real)(c, b->in_vr, b->n_in, u);
        if (st > WARNING) return FB_SET + st;
    }
    double start = b->t0 + (double)(*k) * b->h;
    double end = b->t0 + (double)(*k + b->steps) * b->h;
    call->time = call->origin = start;
    call->end = end;
    call->total = (long long)b->steps * b->substeps;
    call->substep = (end - start) / (double)call->total;
    double ev = call->announced;
    call->next_event = (!isnan(ev) && start < ev && !near(start, ev)) ? ev : NAN;
    int r = fixed_step_advance(spec, call);
    if (r != FS_END) return r;
    *k += b->steps;
    st = b->major == 3 ? ((fmi3GetFloat64TYPE*)b->get_real)(c, b->out_vr, b->n_out, y, b->nv_out)
                       : ((fmi2GetRealTYPE*)b->get_real)(c, b->out_vr, b->n_out, y);
    return st > WARNING ? FB_GET + st : 0;
}

typedef struct {
    const FixedBatch* b;
    const FixedSpec* const* specs;
    FixedCall* const* calls;
    const unsigned char* active;
    const double* inputs;
    double* outputs;
    long long* k;
    int* codes;
    int first;
    int last;
} FixedSlice;

static void* run_fixed_slice(void* arg) {
    const FixedSlice* s = (const FixedSlice*)arg;
    const FixedBatch* b = s->b;
    for (int i = s->first; i < s->last; i++) {
        s->codes[i] = s->active[i] ? batch_one(b, s->specs[i], s->calls[i], s->inputs + (size_t)i * b->nv_in,
                                               s->outputs + (size_t)i * b->nv_out, s->k + i)
                                   : -1;
    }
    return NULL;
}

/* For every active instance i: set its inputs, integrate one sample from step k[i] exactly as
 * fixed_step_advance does for one instance, get its outputs, k[i] += steps; over `threads`
 * threads (each instance has its own work array). codes[i]: 0 done; -1 inactive; FB_SET /
 * FB_GET + status; else the code fixed_step_advance stopped with (an event, termination or a
 * failure): the caller finishes that instance's sample (k[i] unchanged, the instance at
 * calls[i]->time). Returns how many instances the caller must finish. */
int fixed_step_batch(const FixedBatch* b, int n, const FixedSpec* const* specs, FixedCall* const* calls,
                     const unsigned char* active, const double* inputs, double* outputs, long long* k,
                     int* codes, int threads) {
    if (threads > FB_MAX_THREADS) threads = FB_MAX_THREADS;
    if (threads > n) threads = n;
    if (threads < 1) threads = 1;
    FixedSlice slices[FB_MAX_THREADS];
    pthread_t ids[FB_MAX_THREADS];
    bool started[FB_MAX_THREADS];
    for (int t = 0; t < threads; t++) {
        FixedSlice s = {b, specs, calls, active, inputs, outputs, k, codes, (int)((long long)n * t / threads),
                        (int)((long long)n * (t + 1) / threads)};
        slices[t] = s;
        started[t] = false;
    }
    for (int t = 1; t < threads; t++) {
        started[t] = pthread_create(&ids[t], NULL, run_fixed_slice, &slices[t]) == 0;
        if (!started[t]) run_fixed_slice(&slices[t]); /* no thread available: do the slice here */
    }
    run_fixed_slice(&slices[0]);
    for (int t = 1; t < threads; t++) {
        if (started[t]) pthread_join(ids[t], NULL);
    }
    int pending = 0;
    for (int i = 0; i < n; i++) {
        if (codes[i] > 0) pending++;
    }
    return pending;
}
