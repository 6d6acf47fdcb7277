/* One macro step of a system of in-process co-simulation FMUs in one native call.
 *
 * The same FMI calls as the Python master over each component's one-call native sample, in the same
 * order and with the same arguments: for each component, one fmi2SetReal / fmi3SetFloat64 of its
 * inputs, `steps` doStep calls at t = t0 + k*h (k its own integer step counter), one fmi2GetReal /
 * fmi3GetFloat64 of its outputs. A connected input takes its source's output value as it is, or,
 * for a link with `affine` set (a linear transformation and/or unit conversion), `factor * y +
 * offset`: the one expression the Python master's `transform.Affine` computes.
 *
 * Inputs and outputs of other types (Float32, the integer types, Boolean, Enumeration, and FMI 3.0
 * arrays used in part) travel as the Python master's signal groups carry them: the component's
 * values stay float64 in u and y, and each FMI type is a Block with its own typed buffer and one set
 * or get call, in the group's order (an array used in part is read before it is written whole).
 * Before a component steps, each of its inputs is checked as the group checks it (finite; whole and
 * in the type's range; 0 or 1; one of the enumeration's items); a value refused is MASTER_NONFINITE,
 * and the Python path's own check then names it.
 *
 * Jacobi: every connected input is gathered from the outputs of t, then the components check their
 * inputs and step in order. Gauss-Seidel: each component gathers, checks and steps in order.
 * Returns 0, or 1 + the position of the component that failed (its status in status[c]:
 * MASTER_NONFINITE for an input its group refuses, which the Python path then reports; the
 * FMI status of a failed doStep; MASTER_SET / MASTER_GET plus the status of a failed set or get).
 * A component that asks to stop (MASTER_TERMINATED) does not stop the others.
 *
 * With `feedthrough_outputs: updated`, after every macro step the components of `settle` (sources
 * before consumers) gather their connected inputs of t + H, check them, set them and get
 * their outputs again without a step: the Python master's `settle`, with the same calls. A failure
 * there is its status plus MASTER_SETTLING.
 *
 * With max_iterations > 1 (fixed-point iteration), as the Python master iterates: every FMU state
 * and step counter saved, then passes of the macro step, each followed by gathering the connected
 * inputs again from the new outputs, until no input changed by more than tolerance * (1 + |new|)
 * or max_iterations passes were made (then `unconverged` counts the step); between passes every
 * component goes back to the saved state and counter. The states are freed after the step.
 */
#include <math.h>
#include <stddef.h>

#include "fmi2FunctionTypes.h"
#include "fmi3FunctionTypes.h"

#define MASTER_OK 0
#define MASTER_WARNING 1
#define MASTER_DISCARD 2
#define MASTER_TERMINATED 5
#define MASTER_SET 16
#define MASTER_GET 32
#define MASTER_NONFINITE 64 /* an input its signal group refuses: NaN, inf, not whole, out of range, ... */
#define MASTER_SETTLING 128 /* added to a status when it came from settling, not from the step */
#define MASTER_STATE 256    /* + the status of a failed get or set of the FMU state (iteration) */

/* A Block's FMI type, as its buffer holds it (abi.py: BLOCK_KINDS) */
enum { K_F64, K_F32, K_I8, K_U8, K_I16, K_U16, K_I32, K_U32, K_I64, K_U64, K_BOOL_INT, K_BOOL_BYTE };

typedef struct {
    int kind;
    void* set;                /* the typed setter (inputs; NULL for outputs) */
    void* get;                /* the typed getter (outputs; inputs of an array used in part) */
    const unsigned int* vr;
    int n_vr;
    void* buf;                /* nv values of the FMI type */
    int nv;
    int n_el;                 /* the elements of the group in this block */
    const int* pos;           /* u or y index of each element */
    const int* at;            /* buf index of each element */
    int partial;              /* inputs: some elements of an array, so buf is read before it is set */
    const int* enum_first;    /* per element: its first allowed value in items, or -1 (any value) */
    const int* enum_count;
    const double* items;
} Block;

typedef int TypedCall2(void*, const unsigned int*, size_t, void*);
typedef int TypedCall3(void*, const unsigned int*, size_t, void*, size_t);

typedef struct {
    int major;          /* 2 or 3 */
    void* set_real;     /* fmi2SetReal or fmi3SetFloat64 */
    void* get_real;     /* fmi2GetReal or fmi3GetFloat64 */
    void* do_step;      /* fmi2DoStep or fmi3DoStep */
    void* bool_status;  /* fmi2GetBooleanStatus (FMI 2.0 only) */
    void* component;
    int n_in;
    const unsigned int* in_vr;
    double* u;
    int n_out;
    const unsigned int* out_vr;
    double* y;
    double t0;
    double h;
    int steps;
    long long* k;       /* the model's own step counter, advanced in place */
    int nv_in;          /* values of u (FMI 3.0 arrays count every element) */
    int nv_out;         /* values of y */
    void* get_state;    /* fmi2GetFMUstate or fmi3GetFMUState (iteration only) */
    void* set_state;
    void* free_state;
    double* used;       /* iteration: the inputs of the last pass (nv_in values) */
    int n_in_blocks;    /* 0: u is one Float64 buffer set with set_real; else typed blocks */
    const Block* in_blocks;
    int n_out_blocks;   /* 0: y is one Float64 buffer read with get_real; else typed blocks */
    const Block* out_blocks;
} Component;

typedef struct {
    int max_iterations;  /* 1: no iteration */
    double tolerance;
    int last;            /* passes made in the last macro step */
    int unconverged;     /* macro steps that did not converge, added up */
    void** states;       /* one slot per component */
    long long* saved_k;  /* one per component */
} Iteration;

typedef struct {
    int source;  /* position of the source component */
    int i;       /* its output index */
    int target;
    int j;       /* the target's input index */
    double factor;
    double offset;
    int affine;  /* 0: the value passes unchanged; 1: factor * value + offset */
} Link;

static int do_steps2(Component* c) {
    fmi2DoStepTYPE* do_step = (fmi2DoStepTYPE*)c->do_step;
    for (int s = 0; s < c->steps; s++) {
        int st = do_step(c->component, c->t0 + (double)*c->k * c->h, c->h, fmi2True);
        if (st > MASTER_WARNING) {
            fmi2Boolean stop = fmi2False;
            fmi2GetBooleanStatusTYPE* flag = (fmi2GetBooleanStatusTYPE*)c->bool_status;
            if (st == MASTER_DISCARD && flag != NULL &&
                flag(c->component, fmi2Terminated, &stop) <= MASTER_WARNING && stop) {
                *c->k += 1;
                return MASTER_TERMINATED;
            }
            return st;
        }
        *c->k += 1;
    }
    return MASTER_OK;
}

static int do_steps3(Component* c) {
    fmi3DoStepTYPE* do_step = (fmi3DoStepTYPE*)c->do_step;
    for (int s = 0; s < c->steps; s++) {
        fmi3Boolean event = fmi3False, stop = fmi3False, early = fmi3False;
        fmi3Float64 last = 0.0;
        int st = do_step(c->component, c->t0 + (double)*c->k * c->h, c->h, fmi3True, &event, &stop, &early, &last);
        if (st > MASTER_WARNING) return st;
        *c->k += 1;
        if (stop) return MASTER_TERMINATED;
    }
    return MASTER_OK;
}

static int typed_call(void* fn, int major, void* component, const Block* b) {
    return major == 3 ? ((TypedCall3*)fn)(component, b->vr, (size_t)b->n_vr, b->buf, (size_t)b->nv)
                      : ((TypedCall2*)fn)(component, b->vr, (size_t)b->n_vr, b->buf);
}

/* Whether the signal group would take v for element e of b (signals.py's _valid). */
static int valid_value(const Block* b, int e, double v) {
    if (!isfinite(v)) return 0;
    int ok = 1;
    switch (b->kind) {
        case K_F64: case K_F32: return 1;
        case K_BOOL_INT: case K_BOOL_BYTE: return v == 0.0 || v == 1.0;
        case K_I8: ok = v >= -128.0 && v <= 127.0; break;
        case K_U8: ok = v >= 0.0 && v <= 255.0; break;
        case K_I16: ok = v >= -32768.0 && v <= 32767.0; break;
        case K_U16: ok = v >= 0.0 && v <= 65535.0; break;
        case K_I32: ok = v >= -2147483648.0 && v <= 2147483647.0; break;
        case K_U32: ok = v >= 0.0 && v <= 4294967295.0; break;
        case K_I64: ok = v >= -9223372036854775808.0 && v < 9223372036854775808.0; break;
        case K_U64: ok = v >= 0.0 && v < 18446744073709551616.0; break;
        default: return 0;
    }
    if (!ok || floor(v) != v) return 0;
    if (b->enum_first[e] < 0) return 1;
    for (int i = 0; i < b->enum_count[e]; i++) {
        if (b->items[b->enum_first[e] + i] == v) return 1;
    }
    return 0;
}

static void put(const Block* b, const double* u) {
    for (int e = 0; e < b->n_el; e++) {
        double v = u[b->pos[e]];
        int a = b->at[e];
        switch (b->kind) {
            case K_F64: ((double*)b->buf)[a] = v; break;
            case K_F32: ((float*)b->buf)[a] = (float)v; break;
            case K_I8: ((signed char*)b->buf)[a] = (signed char)v; break;
            case K_U8: ((unsigned char*)b->buf)[a] = (unsigned char)v; break;
            case K_I16: ((short*)b->buf)[a] = (short)v; break;
            case K_U16: ((unsigned short*)b->buf)[a] = (unsigned short)v; break;
            case K_I32: ((int*)b->buf)[a] = (int)v; break;
            case K_U32: ((unsigned int*)b->buf)[a] = (unsigned int)v; break;
            case K_I64: ((long long*)b->buf)[a] = (long long)v; break;
            case K_U64: ((unsigned long long*)b->buf)[a] = (unsigned long long)v; break;
            case K_BOOL_INT: ((int*)b->buf)[a] = v != 0.0; break;
            case K_BOOL_BYTE: ((unsigned char*)b->buf)[a] = v != 0.0; break;
        }
    }
}

static void take(const Block* b, double* y) {
    for (int e = 0; e < b->n_el; e++) {
        int a = b->at[e];
        double v = 0.0;
        switch (b->kind) {
            case K_F64: v = ((const double*)b->buf)[a]; break;
            case K_F32: v = (double)((const float*)b->buf)[a]; break;
            case K_I8: v = (double)((const signed char*)b->buf)[a]; break;
            case K_U8: v = (double)((const unsigned char*)b->buf)[a]; break;
            case K_I16: v = (double)((const short*)b->buf)[a]; break;
            case K_U16: v = (double)((const unsigned short*)b->buf)[a]; break;
            case K_I32: v = (double)((const int*)b->buf)[a]; break;
            case K_U32: v = (double)((const unsigned int*)b->buf)[a]; break;
            case K_I64: v = (double)((const long long*)b->buf)[a]; break;
            case K_U64: v = (double)((const unsigned long long*)b->buf)[a]; break;
            case K_BOOL_INT: v = (double)((const int*)b->buf)[a]; break;
            case K_BOOL_BYTE: v = ((const unsigned char*)b->buf)[a] ? 1.0 : 0.0; break;
        }
        y[b->pos[e]] = v;
    }
}

/* The component's inputs set from u: one Float64 call, or one call per typed block. */
static int write_inputs(Component* c) {
    int st;
    if (c->n_in_blocks == 0) {
        if (c->n_in == 0) return MASTER_OK;
        st = c->major == 3 ? ((fmi3SetFloat64TYPE*)c->set_real)(c->component, c->in_vr, c->n_in, c->u, c->nv_in)
                           : ((fmi2SetRealTYPE*)c->set_real)(c->component, c->in_vr, c->n_in, c->u);
        return st > MASTER_WARNING ? MASTER_SET + st : MASTER_OK;
    }
    for (int i = 0; i < c->n_in_blocks; i++) {
        const Block* b = &c->in_blocks[i];
        if (b->partial) {
            st = typed_call(b->get, c->major, c->component, b);
            if (st > MASTER_WARNING) return MASTER_GET + st;
        }
        put(b, c->u);
        st = typed_call(b->set, c->major, c->component, b);
        if (st > MASTER_WARNING) return MASTER_SET + st;
    }
    return MASTER_OK;
}

/* The component's outputs read into y: one Float64 call, or one call per typed block. */
static int read_outputs(Component* c) {
    int st;
    if (c->n_out_blocks == 0) {
        if (c->n_out == 0) return MASTER_OK;
        st = c->major == 3 ? ((fmi3GetFloat64TYPE*)c->get_real)(c->component, c->out_vr, c->n_out, c->y, c->nv_out)
                           : ((fmi2GetRealTYPE*)c->get_real)(c->component, c->out_vr, c->n_out, c->y);
        return st > MASTER_WARNING ? MASTER_GET + st : MASTER_OK;
    }
    for (int i = 0; i < c->n_out_blocks; i++) {
        const Block* b = &c->out_blocks[i];
        st = typed_call(b->get, c->major, c->component, b);
        if (st > MASTER_WARNING) return MASTER_GET + st;
        take(b, c->y);
    }
    return MASTER_OK;
}

static int sample(Component* c) {
    int st = write_inputs(c);
    if (st != MASTER_OK) return st;
    int result = c->major == 3 ? do_steps3(c) : do_steps2(c);
    if (result != MASTER_OK && result != MASTER_TERMINATED) return result;
    st = read_outputs(c);
    return st != MASTER_OK ? st : result;
}

static void gather(Component* comps, const Link* links, int n_links, int target) {
    for (int l = 0; l < n_links; l++) {
        if (target < 0 || links[l].target == target) {
            double y = comps[links[l].source].y[links[l].i];
            comps[links[l].target].u[links[l].j] = links[l].affine ? links[l].factor * y + links[l].offset : y;
        }
    }
}

/* Whether every input is one the component's signal group takes (finite; for typed blocks also
 * whole and in range, 0 or 1, an enumeration item). */
static int valid_inputs(const Component* c) {
    if (c->n_in_blocks == 0) {
        for (int j = 0; j < c->nv_in; j++) {
            if (!isfinite(c->u[j])) return 0;
        }
        return 1;
    }
    for (int i = 0; i < c->n_in_blocks; i++) {
        const Block* b = &c->in_blocks[i];
        for (int e = 0; e < b->n_el; e++) {
            if (!valid_value(b, e, c->u[b->pos[e]])) return 0;
        }
    }
    return 1;
}

static int settle(Component* comps, const Link* links, int n_links, int c) {
    Component* s = &comps[c];
    gather(comps, links, n_links, c);
    if (!valid_inputs(s)) return MASTER_NONFINITE;
    int st = write_inputs(s);
    return st != MASTER_OK ? st : read_outputs(s);
}

static void keep_used(Component* c, int iterating) {
    if (iterating) {
        for (int j = 0; j < c->nv_in; j++) c->used[j] = c->u[j];
    }
}

/* Every component stepped once from the current inputs: 0, or 1 + the position that failed. Each
 * component's inputs are checked just before it steps, as the Python master's write checks them
 * (under Jacobi the components before it have stepped by then, there as here). */
static int pass(Component* comps, int n, const Link* links, int n_links, int gauss_seidel, int* status,
                int iterating) {
    for (int c = 0; c < n; c++) status[c] = MASTER_OK;
    if (!gauss_seidel) gather(comps, links, n_links, -1);
    for (int c = 0; c < n; c++) {
        if (gauss_seidel) gather(comps, links, n_links, c);
        keep_used(&comps[c], iterating);
        if (!valid_inputs(&comps[c])) {
            status[c] = MASTER_NONFINITE;
            return c + 1;
        }
        status[c] = sample(&comps[c]);
        if (status[c] > MASTER_WARNING && status[c] != MASTER_TERMINATED) return c + 1;
    }
    return 0;
}

static int converged(const Component* comps, int n, double tolerance) {
    for (int c = 0; c < n; c++) {
        for (int j = 0; j < comps[c].nv_in; j++) {
            double after = comps[c].u[j];
            if (!(fabs(after - comps[c].used[j]) <= tolerance * (1.0 + fabs(after)))) return 0;
        }
    }
    return 1;
}

static int get_state(Component* c, void** state) {
    *state = NULL;
    return c->major == 3 ? ((fmi3GetFMUStateTYPE*)c->get_state)(c->component, state)
                         : ((fmi2GetFMUstateTYPE*)c->get_state)(c->component, state);
}

static int set_state(Component* c, void* state) {
    return c->major == 3 ? ((fmi3SetFMUStateTYPE*)c->set_state)(c->component, state)
                         : ((fmi2SetFMUstateTYPE*)c->set_state)(c->component, state);
}

static void free_states(Component* comps, int n, void** states) {
    for (int c = 0; c < n; c++) {
        if (states[c] == NULL) continue;
        if (comps[c].major == 3) ((fmi3FreeFMUStateTYPE*)comps[c].free_state)(comps[c].component, &states[c]);
        else ((fmi2FreeFMUstateTYPE*)comps[c].free_state)(comps[c].component, &states[c]);
        states[c] = NULL;
    }
}

static int iterate(Component* comps, int n, const Link* links, int n_links, int gauss_seidel, int* status,
                   Iteration* it) {
    int failed = 0;
    for (int c = 0; c < n; c++) it->states[c] = NULL;
    for (int c = 0; c < n && !failed; c++) {
        int st = get_state(&comps[c], &it->states[c]);
        if (st > MASTER_WARNING) {
            status[c] = MASTER_STATE + st;
            failed = c + 1;
        }
        it->saved_k[c] = *comps[c].k;
    }
    for (int pass_no = 1; !failed && pass_no <= it->max_iterations; pass_no++) {
        failed = pass(comps, n, links, n_links, gauss_seidel, status, 1);
        if (failed) break;
        it->last = pass_no;
        gather(comps, links, n_links, -1);
        if (converged(comps, n, it->tolerance)) break;
        if (pass_no == it->max_iterations) {
            it->unconverged += 1;
            break;
        }
        for (int c = 0; c < n; c++) {  /* back to t; the outputs stay those at t + H */
            int st = set_state(&comps[c], it->states[c]);
            if (st > MASTER_WARNING) {
                status[c] = MASTER_STATE + st;
                failed = c + 1;
                break;
            }
            *comps[c].k = it->saved_k[c];
        }
    }
    free_states(comps, n, it->states);
    return failed;
}

int master_step(Component* comps, int n, const Link* links, int n_links, int gauss_seidel, int* status,
                int n_settle, const int* settle_order, Iteration* it) {
    int failed = it->max_iterations > 1 ? iterate(comps, n, links, n_links, gauss_seidel, status, it)
                                        : pass(comps, n, links, n_links, gauss_seidel, status, 0);
    if (failed) return failed;
    for (int i = 0; i < n_settle; i++) {
        int c = settle_order[i];
        int st = settle(comps, links, n_links, c);
        if (st > MASTER_WARNING) {
            status[c] = MASTER_SETTLING + st;
            return c + 1;
        }
    }
    return 0;
}

/* Up to `count` macro steps (one sample of several): stops after a macro step in which a
 * component asked to stop, or at a failure (master_step's return). `done` counts the macro steps
 * completed, the one with the stop request included, the failed one not. */
int master_run(Component* comps, int n, const Link* links, int n_links, int gauss_seidel, int* status, int count,
               int* done, int n_settle, const int* settle_order, Iteration* it) {
    *done = 0;
    for (int r = 0; r < count; r++) {
        int failed = master_step(comps, n, links, n_links, gauss_seidel, status, n_settle, settle_order, it);
        if (failed) return failed;
        *done = r + 1;
        for (int c = 0; c < n; c++) {
            if (status[c] == MASTER_TERMINATED) return 0;
        }
    }
    return 0;
}

/* One sample of the system as its task sees it: the task's inputs set into the components'
 * input arrays, `count` macro steps (master_run), the observed outputs gathered into `obs`.
 * All arrays are the caller's and stay bound between calls, so a sample allocates nothing. */
typedef struct {
    Component* comps;
    int n;
    const Link* links;
    int n_links;
    int gauss_seidel;
    int* status;
    int n_ext;            /* the task's inputs: ext[e] -> comps[ext_comp[e]].u[ext_j[e]] */
    const int* ext_comp;
    const int* ext_j;
    const double* ext;
    int n_obs;            /* the observation: comps[obs_comp[o]].y[obs_i[o]] -> obs[o] */
    const int* obs_comp;
    const int* obs_i;
    double* obs;
    int done;             /* macro steps completed by the last call */
    int stopped;          /* 1 if a component asked to stop in the last call */
    int n_settle;         /* feedthrough_outputs: updated: the components settled after each step */
    const int* settle;
    Iteration iteration;
} Sample;

/* Returns master_run's failure (1 + position), else -1 if a component asked to stop, else 0 (every
 * component stepped `count` macro steps with OK). */
int master_sample(Sample* s, int count, int with_inputs) {
    if (with_inputs) {
        for (int e = 0; e < s->n_ext; e++) s->comps[s->ext_comp[e]].u[s->ext_j[e]] = s->ext[e];
    }
    int failed = master_run(s->comps, s->n, s->links, s->n_links, s->gauss_seidel, s->status, count, &s->done,
                            s->n_settle, s->settle, &s->iteration);
    s->stopped = 0;
    for (int c = 0; c < s->n; c++) {
        if (s->status[c] == MASTER_TERMINATED) s->stopped = 1;
    }
    if (failed) return failed;
    for (int o = 0; o < s->n_obs; o++) s->obs[o] = s->comps[s->obs_comp[o]].y[s->obs_i[o]];
    return s->stopped ? -1 : 0;
}
