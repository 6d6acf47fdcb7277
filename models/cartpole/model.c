/* Cart-pole with the equations of gymnasium's CartPole (classic_control/cartpole.py), integrated
 * with RK4 substeps instead of gymnasium's explicit Euler step. */
#include "fmu_core.h"

#include <math.h>

FmuStatus model_initialize(FmuInstance* inst) {
    ModelData* d = &inst->s.d;
    if (!(d->m_cart > 0.0) || !(d->m_pole > 0.0) || !(d->length > 0.0)) {
        fmu_log_error(inst, "cartpole: m_cart, m_pole and length must be > 0, got %g kg, %g kg, %g m; "
                      "set positive values before initialization", d->m_cart, d->m_pole, d->length);
        return FMU_ERROR;
    }
    if (!(d->solver_step > 0.0) || !(d->track_limit >= 0.0)) {
        fmu_log_error(inst, "cartpole: solver_step must be > 0 and track_limit >= 0, got %g s and %g m",
                      d->solver_step, d->track_limit);
        return FMU_ERROR;
    }
    d->x = d->x0;
    d->x_dot = d->x_dot0;
    d->theta = d->theta0;
    d->theta_dot = d->theta_dot0;
    return FMU_OK;
}

void model_evaluate(FmuInstance* inst) {
    ModelData* d = &inst->s.d;
    const double total_mass = d->m_cart + d->m_pole;
    const double polemass_length = d->m_pole * d->length;
    const double sin_theta = sin(d->theta);
    const double cos_theta = cos(d->theta);
    const double temp = (d->force + polemass_length * d->theta_dot * d->theta_dot * sin_theta) / total_mass;
    const double thetaacc = (d->g * sin_theta - cos_theta * temp) /
                            (d->length * (4.0 / 3.0 - d->m_pole * cos_theta * cos_theta / total_mass));
    const double xacc = temp - polemass_length * thetaacc * cos_theta / total_mass;
    d->der_x = d->x_dot;
    d->der_x_dot = xacc;
    d->der_theta = d->theta_dot;
    d->der_theta_dot = thetaacc;
    d->track_margin = d->track_limit > 0.0 ? d->track_limit - fabs(d->x) : 1.0;
}

static void request_termination(FmuInstance* inst) {
    const ModelData* d = &inst->s.d;
    inst->s.terminate_requested = true;
    fmu_log_event(inst, "cartpole: |x| = %g m reached track_limit = %g m at t = %g s; requesting termination",
                  fabs(d->x), d->track_limit, inst->s.time);
}

void model_event_update(FmuInstance* inst, FmuEventResult* ev) {
    const ModelData* d = &inst->s.d;
    if (d->track_limit > 0.0 && fabs(d->x) >= d->track_limit) {
        ev->terminate_simulation = true;
        request_termination(inst);
    }
}

FmuStatus model_do_step(FmuInstance* inst, double h) {
    ModelData* d = &inst->s.d;
    fmu_rk4(inst, h, d->solver_step);
    /* the whole step is completed, so outputs always belong to t + h (see models/README.md) */
    if (d->track_limit > 0.0 && fabs(d->x) > d->track_limit) request_termination(inst);
    return FMU_OK;
}
