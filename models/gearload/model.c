/* Gearbox (ratio N) and compliant output shaft (k, d) driving a load inertia J:
 *   dphi/dt   = omega_in / N - omega
 *   tau_shaft = k phi + d dphi/dt
 *   J domega/dt = tau_shaft - b omega - tau_ext
 *   torque (on the motor shaft) = tau_shaft / N */
#include "fmu_core.h"

FmuStatus model_initialize(FmuInstance* inst) {
    ModelData* d = &inst->s.d;
    if (!(d->N > 0.0) || !(d->k > 0.0) || !(d->d >= 0.0) || !(d->J > 0.0) || !(d->b >= 0.0)) {
        fmu_log_error(inst, "gearload: N, k and J must be > 0 and d, b >= 0, got N = %g, k = %g N.m/rad, "
                      "d = %g N.m.s/rad, J = %g kg.m2, b = %g N.m.s/rad", d->N, d->k, d->d, d->J, d->b);
        return FMU_ERROR;
    }
    if (!(d->solver_step > 0.0)) {
        fmu_log_error(inst, "gearload: solver_step must be > 0, got %g s", d->solver_step);
        return FMU_ERROR;
    }
    d->phi = d->phi0;
    d->omega = d->omega0;
    return FMU_OK;
}

void model_evaluate(FmuInstance* inst) {
    ModelData* d = &inst->s.d;
    d->der_phi = d->omega_in / d->N - d->omega;
    const double tau_shaft = d->k * d->phi + d->d * d->der_phi;
    d->torque = tau_shaft / d->N;
    d->der_omega = (tau_shaft - d->b * d->omega - d->tau_ext) / d->J;
}

void model_event_update(FmuInstance* inst, FmuEventResult* ev) {
    (void)inst;
    (void)ev;   /* no events: linear time-invariant */
}

FmuStatus model_do_step(FmuInstance* inst, double h) {
    fmu_rk4(inst, h, inst->s.d.solver_step);
    return FMU_OK;
}
