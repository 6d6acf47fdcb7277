/* A slow plant: dx/dt = (u - x) / tau, whose doStep sleeps step_delay_s and whose exit of
 * initialisation sleeps init_delay_s of wall-clock time. It sleeps rather than computes so that a
 * test can make it slow without loading the machine; to every importer it looks like a plant whose
 * solver takes that long. */
#define _POSIX_C_SOURCE 199309L
#include <errno.h>
#include <math.h>
#include <time.h>

#include "fmu_core.h"

static void sleep_s(double seconds) {
    if (!(seconds > 0.0)) return;
    struct timespec left;
    left.tv_sec = (time_t)floor(seconds);
    left.tv_nsec = (long)((seconds - floor(seconds)) * 1e9);
    while (nanosleep(&left, &left) == -1 && errno == EINTR) {
    }
}

FmuStatus model_initialize(FmuInstance* inst) {
    ModelData* d = &inst->s.d;
    if (!(d->tau > 0.0) || !(d->step_delay_s >= 0.0) || !(d->init_delay_s >= 0.0)) {
        fmu_log_error(inst, "slow_plant: need tau > 0 and step_delay_s, init_delay_s >= 0, got tau = %g s, "
                      "step_delay_s = %g s, init_delay_s = %g s", d->tau, d->step_delay_s, d->init_delay_s);
        return FMU_ERROR;
    }
    sleep_s(d->init_delay_s);
    d->x = d->x0;
    return FMU_OK;
}

void model_evaluate(FmuInstance* inst) {
    ModelData* d = &inst->s.d;
    d->der_x = (d->u - d->x) / d->tau;
}

void model_event_update(FmuInstance* inst, FmuEventResult* ev) {
    (void)inst;
    (void)ev; /* co-simulation only */
}

FmuStatus model_do_step(FmuInstance* inst, double h) {
    sleep_s(inst->s.d.step_delay_s);
    fmu_rk4(inst, h, 0.01);
    return FMU_OK;
}
