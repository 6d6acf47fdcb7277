/* Batched co-simulation stepping: N instances of one FMU in one call.
 *
 * For every active instance i: write its inputs (one fmi2SetReal / fmi3SetFloat64 call), run
 * `steps` doStep calls at t = t0 + k*h (k is the instance's own integer step counter, updated
 * here), read its outputs (one fmi2GetReal / fmi3GetFloat64 call). The FMU's functions come as
 * pointers resolved from the FMU's own shared library, so the calls are exactly those the
 * per-instance path makes, in the same order, with the same arguments. An FMI 3.0 array is one value
 * reference whose elements all travel in the call (nValues counts every element, row-major), so
 * n_in/n_out count value references and nv_in/nv_out values (the rows of inputs and outputs).
 *
 * status[i] is the FMI status of the call that decided the instance's fate: OK/Warning, the
 * doStep status on failure, BATCH_TERMINATED when the FMU asked to stop (FMI 2.0: Discard with
 * fmi2Terminated; FMI 3.0: terminateSimulation), or BATCH_SET / BATCH_GET added to the status of
 * a failed set or get. An error in one instance never stops the others.
 */
#include <pthread.h>
#include <stdbool.h>
#include <stddef.h>

#include "fmi2FunctionTypes.h"
#include "fmi3FunctionTypes.h"

#define BATCH_OK 0
#define BATCH_WARNING 1
#define BATCH_DISCARD 2
#define BATCH_TERMINATED 5
#define BATCH_SET 16
#define BATCH_GET 32
#define BATCH_INACTIVE -1
#define BATCH_MAX_THREADS 64

typedef struct {
    int major;          /* 2 or 3 */
    void* set_real;     /* fmi2SetReal or fmi3SetFloat64 */
    void* get_real;     /* fmi2GetReal or fmi3GetFloat64 */
    void* do_step;      /* fmi2DoStep or fmi3DoStep */
    void* bool_status;  /* fmi2GetBooleanStatus (FMI 2.0 only) */
    int n_in;
    const unsigned int* in_vr;
    int n_out;
    const unsigned int* out_vr;
    double t0;
    double h;
    int steps;
    int nv_in;          /* values of the inputs: n_in for scalars, FMI 3.0 arrays count every element */
    int nv_out;         /* values of the outputs */
} BatchSpec;

typedef struct {
    const BatchSpec* spec;
    void* const* comps;
    const unsigned char* active;
    const double* inputs;
    double* outputs;
    long long* k;
    int* status;
    int first;
    int last;
} BatchSlice;

static int step2(const BatchSpec* s, void* c, long long* k) {
    fmi2DoStepTYPE* do_step = (fmi2DoStepTYPE*)s->do_step;
    for (int j = 0; j < s->steps; j++) {
        int st = do_step(c, s->t0 + (double)(*k) * s->h, s->h, fmi2True);
        if (st > BATCH_WARNING) {
            fmi2Boolean stop = fmi2False;
            fmi2GetBooleanStatusTYPE* flag = (fmi2GetBooleanStatusTYPE*)s->bool_status;
            if (st == BATCH_DISCARD && flag != NULL && flag(c, fmi2Terminated, &stop) <= BATCH_WARNING && stop) {
                *k += 1;
                return BATCH_TERMINATED;
            }
            return st;
        }
        *k += 1;
    }
    return BATCH_OK;
}

static int step3(const BatchSpec* s, void* c, long long* k) {
    fmi3DoStepTYPE* do_step = (fmi3DoStepTYPE*)s->do_step;
    for (int j = 0; j < s->steps; j++) {
        fmi3Boolean event = fmi3False, stop = fmi3False, early = fmi3False;
        fmi3Float64 last = 0.0;
        int st = do_step(c, s->t0 + (double)(*k) * s->h, s->h, fmi3True, &event, &stop, &early, &last);
        if (st > BATCH_WARNING) return st;
        *k += 1;
        if (stop) return BATCH_TERMINATED;
    }
    return BATCH_OK;
}

static int one(const BatchSpec* s, void* c, const double* u, double* y, long long* k) {
    int st;
    if (s->n_in > 0) {
        st = s->major == 3 ? ((fmi3SetFloat64TYPE*)s->set_real)(c, s->in_vr, s->n_in, u, s->nv_in)
                           : ((fmi2SetRealTYPE*)s->set_real)(c, s->in_vr, s->n_in, u);
        if (st > BATCH_WARNING) return BATCH_SET + st;
    }
    int result = s->major == 3 ? step3(s, c, k) : step2(s, c, k);
    if (result != BATCH_OK) {
        if (result != BATCH_TERMINATED) return result;
    }
    st = s->major == 3 ? ((fmi3GetFloat64TYPE*)s->get_real)(c, s->out_vr, s->n_out, y, s->nv_out)
                       : ((fmi2GetRealTYPE*)s->get_real)(c, s->out_vr, s->n_out, y);
    if (st > BATCH_WARNING) return BATCH_GET + st;
    return result;
}

static void* run_slice(void* arg) {
    const BatchSlice* b = (const BatchSlice*)arg;
    const BatchSpec* s = b->spec;
    for (int i = b->first; i < b->last; i++) {
        if (!b->active[i]) {
            b->status[i] = BATCH_INACTIVE;
            continue;
        }
        b->status[i] = one(s, b->comps[i], b->inputs + (size_t)i * s->nv_in, b->outputs + (size_t)i * s->nv_out,
                           b->k + i);
    }
    return NULL;
}

/* Step instances 0..n-1 over `threads` threads (1: this thread); returns how many failed. */
int batch_step(const BatchSpec* spec, int n, void* const* comps, const unsigned char* active,
               const double* inputs, double* outputs, long long* k, int* status, int threads) {
    if (threads > BATCH_MAX_THREADS) threads = BATCH_MAX_THREADS;
    if (threads > n) threads = n;
    if (threads < 1) threads = 1;
    BatchSlice slices[BATCH_MAX_THREADS];
    pthread_t ids[BATCH_MAX_THREADS];
    bool started[BATCH_MAX_THREADS];
    for (int t = 0; t < threads; t++) {
        BatchSlice b = {spec, comps, active, inputs, outputs, k, status, (int)((long long)n * t / threads),
                        (int)((long long)n * (t + 1) / threads)};
        slices[t] = b;
        started[t] = false;
    }
    for (int t = 1; t < threads; t++) {
        started[t] = pthread_create(&ids[t], NULL, run_slice, &slices[t]) == 0;
        if (!started[t]) run_slice(&slices[t]); /* no thread available: do the slice here */
    }
    run_slice(&slices[0]);
    for (int t = 1; t < threads; t++) {
        if (started[t]) pthread_join(ids[t], NULL);
    }
    int failed = 0;
    for (int i = 0; i < n; i++) {
        if (status[i] > BATCH_WARNING) failed++;
    }
    return failed;
}

/* One sample of one instance (the single plant's hot path): the same calls as batch_step. */
int step_one(const BatchSpec* spec, void* comp, const double* inputs, double* outputs, long long* k) {
    return one(spec, comp, inputs, outputs, k);
}

/* The doStep-only loop over the same instances (no inputs, no outputs): the benchmark's floor. */
int batch_do_steps(const BatchSpec* spec, int n, void* const* comps, long long* k, int samples) {
    int failed = 0;
    for (int j = 0; j < samples; j++) {
        for (int i = 0; i < n; i++) {
            int st = spec->major == 3 ? step3(spec, comps[i], k + i) : step2(spec, comps[i], k + i);
            if (st > BATCH_WARNING) failed++;
        }
    }
    return failed;
}
