/* Permanent-magnet DC motor:
 *   L di/dt     = voltage - R i - K omega
 *   J domega/dt = K i - b omega - load_torque */
#include "fmu_core.h"

FmuStatus model_initialize(FmuInstance* inst) {
    ModelData* d = &inst->s.d;
    if (!(d->R > 0.0) || !(d->L > 0.0) || !(d->K > 0.0) || !(d->J > 0.0) || !(d->b >= 0.0)) {
        fmu_log_error(inst, "dcmotor: R, L, K and J must be > 0 and b >= 0, got R = %g Ohm, L = %g H, "
                      "K = %g N.m/A, J = %g kg.m2, b = %g N.m.s/rad", d->R, d->L, d->K, d->J, d->b);
        return FMU_ERROR;
    }
    if (!(d->solver_step > 0.0)) {
        fmu_log_error(inst, "dcmotor: solver_step must be > 0, got %g s", d->solver_step);
        return FMU_ERROR;
    }
    d->current = d->i0;
    d->omega = d->omega0;
    return FMU_OK;
}

void model_evaluate(FmuInstance* inst) {
    ModelData* d = &inst->s.d;
    d->torque = d->K * d->current;
    d->der_current = (d->voltage - d->R * d->current - d->K * d->omega) / d->L;
    d->der_omega = (d->torque - d->b * d->omega - d->load_torque) / d->J;
}

void model_event_update(FmuInstance* inst, FmuEventResult* ev) {
    (void)inst;
    (void)ev;   /* no events: the motor is a linear time-invariant system */
}

FmuStatus model_do_step(FmuInstance* inst, double h) {
    fmu_rk4(inst, h, inst->s.d.solver_step);
    return FMU_OK;
}
