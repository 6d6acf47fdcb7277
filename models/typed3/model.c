/* Test model for FMI 3.0 arrays, Binary and clocks. Each doStep holds the input array u over the step:
 * y[2,j] integrates it, y[1,j] takes its value; data_out is data_in reversed; ticks counts the intervals of
 * the clock tick completed since the start time. */
#include "fmu_core.h"

#include <math.h>

#define N_U 3

/* data_out = data_in reversed, and its size and byte sum. */
static bool reverse_data(ModelData* d) {
    const FmuBinary* in = &d->data_in;
    if (!fmu_binary_assign(&d->data_out, in->data, in->size)) return false;
    double sum = 0.0;
    for (size_t k = 0; k < in->size; k++) {
        d->data_out.data[k] = in->data[in->size - 1 - k];
        sum += in->data[k];
    }
    d->data_size = (int32_t)in->size;
    d->data_sum = sum;
    return true;
}

static int32_t completed_ticks(double elapsed_s) {
    /* a tick that falls on a communication point belongs to the step that ends there */
    return (int32_t)floor(elapsed_s / MODEL_VARIABLES[VR_tick].interval + 1e-9);
}

FmuStatus model_initialize(FmuInstance* inst) {
    ModelData* d = &inst->s.d;
    d->t0 = inst->s.time;
    d->ticks = 0;
    for (int j = 0; j < N_U; j++) {
        d->y[j] = d->u[j];
        d->y[N_U + j] = 0.0;
    }
    if (!reverse_data(d)) {
        fmu_log_error(inst, "typed3: out of memory while copying data_in");
        return FMU_FATAL;
    }
    return FMU_OK;
}

void model_evaluate(FmuInstance* inst) {
    (void)inst; /* every output changes at doStep only */
}

void model_event_update(FmuInstance* inst, FmuEventResult* ev) {
    (void)inst;
    (void)ev; /* co-simulation only */
}

FmuStatus model_do_step(FmuInstance* inst, double h) {
    ModelData* d = &inst->s.d;
    for (int j = 0; j < N_U; j++) {
        d->y[N_U + j] += d->u[j] * h;
        d->y[j] = d->u[j];
    }
    d->ticks = completed_ticks(inst->s.time + h - d->t0);
    if (!reverse_data(d)) {
        fmu_log_error(inst, "typed3: out of memory while copying data_in");
        return FMU_FATAL;
    }
    return FMU_OK;
}
