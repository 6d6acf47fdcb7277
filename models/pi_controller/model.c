/* PI controller: e = reference - measurement, v = kp e + ki integral, u = clamp(v, u_min, u_max);
 * d integral/dt = e, except 0 while v is clamped and e would push it further (anti-windup). */
#include "fmu_core.h"

FmuStatus model_initialize(FmuInstance* inst) {
    ModelData* d = &inst->s.d;
    if (!(d->u_max > d->u_min)) {
        fmu_log_error(inst, "pi_controller: u_max must be > u_min, got u_min = %g, u_max = %g", d->u_min, d->u_max);
        return FMU_ERROR;
    }
    if (!(d->solver_step > 0.0)) {
        fmu_log_error(inst, "pi_controller: solver_step must be > 0, got %g s", d->solver_step);
        return FMU_ERROR;
    }
    d->integral = d->integral0;
    return FMU_OK;
}

void model_evaluate(FmuInstance* inst) {
    ModelData* d = &inst->s.d;
    d->error = d->reference - d->measurement;
    const double v = d->kp * d->error + d->ki * d->integral;
    d->u = v > d->u_max ? d->u_max : (v < d->u_min ? d->u_min : v);
    const int windup = (v > d->u_max && d->error * d->ki > 0.0) || (v < d->u_min && d->error * d->ki < 0.0);
    d->der_integral = windup ? 0.0 : d->error;
}

void model_event_update(FmuInstance* inst, FmuEventResult* ev) {
    (void)inst;
    (void)ev;
}

FmuStatus model_do_step(FmuInstance* inst, double h) {
    fmu_rk4(inst, h, inst->s.d.solver_step);
    return FMU_OK;
}
