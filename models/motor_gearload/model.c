/* dcmotor and gearload coupled exactly (no co-simulation delay):
 *   L di/dt = voltage - R i - K omega_motor
 *   J_motor domega_motor/dt = K i - b_motor omega_motor - torque
 *   dphi/dt = omega_motor / N - omega,  torque = (k phi + d dphi/dt) / N
 *   J_load domega/dt = N torque - b_load omega - tau_ext */
#include "fmu_core.h"

FmuStatus model_initialize(FmuInstance* inst) {
    ModelData* d = &inst->s.d;
    if (!(d->R > 0.0) || !(d->L > 0.0) || !(d->K > 0.0) || !(d->J_motor > 0.0) || !(d->N > 0.0) ||
        !(d->k > 0.0) || !(d->J_load > 0.0) || !(d->solver_step > 0.0)) {
        fmu_log_error(inst, "motor_gearload: R, L, K, J_motor, N, k, J_load and solver_step must be > 0");
        return FMU_ERROR;
    }
    d->current = 0.0;
    d->omega_motor = 0.0;
    d->phi = 0.0;
    d->omega = 0.0;
    return FMU_OK;
}

void model_evaluate(FmuInstance* inst) {
    ModelData* d = &inst->s.d;
    d->der_phi = d->omega_motor / d->N - d->omega;
    const double tau_shaft = d->k * d->phi + d->d * d->der_phi;
    d->torque = tau_shaft / d->N;
    d->der_current = (d->voltage - d->R * d->current - d->K * d->omega_motor) / d->L;
    d->der_omega_motor = (d->K * d->current - d->b_motor * d->omega_motor - d->torque) / d->J_motor;
    d->der_omega = (tau_shaft - d->b_load * d->omega - d->tau_ext) / d->J_load;
}

void model_event_update(FmuInstance* inst, FmuEventResult* ev) {
    (void)inst;
    (void)ev;
}

FmuStatus model_do_step(FmuInstance* inst, double h) {
    fmu_rk4(inst, h, inst->s.d.solver_step);
    return FMU_OK;
}
