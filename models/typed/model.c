/* Test model covering every FMI variable type. Each doStep increments counter, integrates real_in,
 * then copies every input to its output; fail_at_step and terminate_at_time are failure hooks. */
#include "fmu_core.h"

#include <stdlib.h>
#include <string.h>
#ifndef _WIN32
#include <unistd.h>
#endif

static bool copy_string(char** dst, const char* src) {
    char* copy = malloc(strlen(src) + 1);
    if (copy == NULL) return false;
    strcpy(copy, src);
    free(*dst);
    *dst = copy;
    return true;
}

/* Outputs take the current inputs (FMI 3.0-only fields exist in every build and are simply unused in FMI 2.0). */
static bool copy_inputs_to_outputs(ModelData* d) {
    d->real_out = d->real_in;
    d->integer_out = d->integer_in;
    d->boolean_out = d->boolean_in;
    d->enum_out = d->enum_in;
    d->float32_out = d->float32_in;
    d->int8_out = d->int8_in;
    d->uint8_out = d->uint8_in;
    d->int16_out = d->int16_in;
    d->uint16_out = d->uint16_in;
    d->uint32_out = d->uint32_in;
    d->int64_out = d->int64_in;
    d->uint64_out = d->uint64_in;
    d->real_scaled = d->gain * d->real_in;
    return copy_string(&d->string_out, d->string_in);
}

FmuStatus model_initialize(FmuInstance* inst) {
    ModelData* d = &inst->s.d;
    d->counter = 0;
    d->real_integral = 0.0;
    d->double_gain = 2.0 * d->gain;
    if (d->real_param > d->init_fails_above) {
        fmu_log_error(inst, "typed: real_param = %g is above init_fails_above = %g: initialisation refused (test hook)",
                      d->real_param, d->init_fails_above);
        return FMU_ERROR;
    }
    if (!copy_inputs_to_outputs(d)) {
        fmu_log_error(inst, "typed: out of memory while copying string_in");
        return FMU_FATAL;
    }
    return FMU_OK;
}

void model_evaluate(FmuInstance* inst) {
    ModelData* d = &inst->s.d;
    d->double_gain = 2.0 * d->gain;   /* gain is tunable, so its calculated parameter follows it */
}

void model_event_update(FmuInstance* inst, FmuEventResult* ev) {
    (void)inst;
    (void)ev;   /* co-simulation only */
}

/* Test hooks for process isolation: what an unstable FMU from elsewhere may do. */
static char* volatile leaked; /* escapes, so the compiler cannot drop the leaking allocation */

static void misbehave(int kind) {
    if (kind == 1) {
        volatile int spin = 1;
        while (spin) {
        }
    } else if (kind == 2) {
        volatile int* volatile nowhere = NULL;
        *nowhere = 1;
    } else if (kind == 3) {
        char* leak = malloc(1u << 20);
        if (leak != NULL) {
            memset(leak, 1, 1u << 20); /* touched, so it counts as resident memory */
            leaked = leak;
        }
    } else if (kind == 4) {
#ifndef _WIN32
        (void)fork(); /* parent and child both loop: a deadline must stop the pair */
#endif
        misbehave(1);
    } else if (kind == 5) {
        const size_t size = (size_t)4 << 30;
        char* huge = malloc(size);
        if (huge == NULL) abort(); /* what most code does with a failed allocation, one way or another */
        memset(huge, 1, size);
        leaked = huge;
    } else if (kind == 6) {
        exit(0); /* a model that ends the process it runs in */
    }
}

FmuStatus model_do_step(FmuInstance* inst, double h) {
    ModelData* d = &inst->s.d;
    const double t_end = inst->s.time + h;
    d->counter += 1;
    if (d->fail_at_step >= 0 && d->counter == d->fail_at_step) {
        fmu_log_error(inst, "typed: fail_at_step reached: doStep call %d at t = %g s fails on purpose (test hook)",
                      (int)d->counter, inst->s.time);
        return FMU_ERROR;
    }
    if (d->fault_at_step >= 0 && d->counter >= d->fault_at_step) {
        misbehave(d->fault_kind);
    }
    d->real_integral += d->real_in * h;
    if (!copy_inputs_to_outputs(d)) {
        fmu_log_error(inst, "typed: out of memory while copying string_in");
        return FMU_FATAL;
    }
    if (d->terminate_at_time >= 0.0 && t_end > d->terminate_at_time) {
        inst->s.terminate_requested = true;
        fmu_log_event(inst, "typed: t = %g s is beyond terminate_at_time = %g s; requesting termination", t_end,
                      d->terminate_at_time);
    }
    return FMU_OK;
}
