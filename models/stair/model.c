/* Stair: der(x) = rate; ticks at t = k * period (time events in model exchange) add the discrete input
 * step to stair and sample x into held. Co-simulation locates the ticks inside a step exactly (x is
 * linear in t between ticks, as inputs are held over a step). */
#include "fmu_core.h"

#include <math.h>

static double next_tick(const ModelData* d) { return (d->ticks + 1) * d->period; }

static bool tick_due(const ModelData* d, double time) { return time >= next_tick(d) - 1e-9 * d->period; }

static void tick(FmuInstance* inst) {
    ModelData* d = &inst->s.d;
    d->ticks += 1;
    d->stair += d->step;
    d->held = d->x;
    fmu_log_event(inst, "stair: tick %d at t = %.17g s, stair = %d", (int)d->ticks, inst->s.time, (int)d->stair);
}

FmuStatus model_initialize(FmuInstance* inst) {
    ModelData* d = &inst->s.d;
    if (!(d->period > 0.0)) {
        fmu_log_error(inst, "stair: need period > 0, got period = %g s", d->period);
        return FMU_ERROR;
    }
    d->x = d->x0;
    d->held = d->x0;
    d->stair = 0;
    d->ticks = (int32_t)floor(inst->s.time / d->period + 1e-9);
    return FMU_OK;
}

void model_evaluate(FmuInstance* inst) {
    ModelData* d = &inst->s.d;
    d->der_x = d->rate;
    d->y = d->x + d->offset;
}

void model_event_update(FmuInstance* inst, FmuEventResult* ev) {
    ModelData* d = &inst->s.d;
    while (tick_due(d, inst->s.time)) tick(inst);
    ev->next_event_time_defined = true;
    ev->next_event_time = next_tick(d);
}

FmuStatus model_do_step(FmuInstance* inst, double h) {
    ModelData* d = &inst->s.d;
    double t = inst->s.time;
    const double t_end = t + h;
    while (tick_due(d, t_end)) {
        const double t_tick = next_tick(d) < t_end ? next_tick(d) : t_end;
        d->x += d->rate * (t_tick - t);
        t = t_tick;
        tick(inst);
    }
    d->x += d->rate * (t_end - t);
    return FMU_OK;
}
