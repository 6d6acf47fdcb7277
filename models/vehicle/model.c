/* Vehicle lateral dynamics: single-track model in path coordinates.
 *
 *   alpha_f = delta - atan((v_y + lf r) / v_x),  alpha_r = -atan((v_y - lr r) / v_x)
 *   F(alpha) = D sin(C atan(B alpha)),  D = mu Fz,  B = C_alpha / (C D)   (magic formula, E = 0)
 *   m (dv_y/dt + v_x r) = Fyf cos(delta) + Fyr,   Iz dr/dt = lf Fyf cos(delta) - lr Fyr
 *   de_y/dt = v_y cos(e_psi) + v_x sin(e_psi),  ds/dt = (v_x cos(e_psi) - v_y sin(e_psi)) / (1 - kappa e_y)
 *   de_psi/dt = r - kappa ds/dt
 *   ddelta/dt = rate_max tanh((sat(steer_cmd) - delta) / (tau rate_max))
 *
 * Static axle loads Fzf = m g lr / (lf + lr), Fzr = m g lf / (lf + lr). The steering actuator is
 * first order with time constant tau for small commands and saturates smoothly at rate_max. */
#include <math.h>

#include "fmu_core.h"

static double tyre_force(double alpha, double stiffness, double shape, double peak) {
    double b = stiffness / (shape * peak);
    return peak * sin(shape * atan(b * alpha));
}

FmuStatus model_initialize(FmuInstance* inst) {
    ModelData* d = &inst->s.d;
    if (!(d->m > 0.0) || !(d->Iz > 0.0) || !(d->lf > 0.0) || !(d->lr > 0.0) || !(d->Cf > 0.0) ||
        !(d->Cr > 0.0) || !(d->mu > 0.0) || !(d->g > 0.0)) {
        fmu_log_error(inst, "vehicle: m, Iz, lf, lr, Cf, Cr, mu and g must be > 0, got m = %g kg, "
                      "Iz = %g kg.m2, lf = %g m, lr = %g m, Cf = %g N/rad, Cr = %g N/rad, mu = %g, "
                      "g = %g m/s2", d->m, d->Iz, d->lf, d->lr, d->Cf, d->Cr, d->mu, d->g);
        return FMU_ERROR;
    }
    if (!(d->shape > 1.0) || !(d->shape < 2.0)) {
        fmu_log_error(inst, "vehicle: shape must be in (1, 2), got %g", d->shape);
        return FMU_ERROR;
    }
    if (!(d->delta_max > 0.0) || !(d->steer_rate_max > 0.0) || !(d->steer_tau > 0.0) ||
        !(d->v_min > 0.0) || !(d->solver_step > 0.0)) {
        fmu_log_error(inst, "vehicle: delta_max, steer_rate_max, steer_tau, v_min and solver_step must be "
                      "> 0, got %g rad, %g rad/s, %g s, %g m/s, %g s", d->delta_max, d->steer_rate_max,
                      d->steer_tau, d->v_min, d->solver_step);
        return FMU_ERROR;
    }
    d->lateral_error = d->e_y0;
    d->heading_error = d->e_psi0;
    d->lateral_velocity = 0.0;
    d->yaw_rate = 0.0;
    d->steer_angle = 0.0;
    d->distance = 0.0;
    return FMU_OK;
}

void model_evaluate(FmuInstance* inst) {
    ModelData* d = &inst->s.d;
    double vx = d->v_x > d->v_min ? d->v_x : d->v_min;
    double vy = d->lateral_velocity, r = d->yaw_rate, delta = d->steer_angle;
    double e_y = d->lateral_error, e_psi = d->heading_error, kappa = d->path_curvature;
    double wheelbase = d->lf + d->lr;
    double fzf = d->m * d->g * d->lr / wheelbase, fzr = d->m * d->g * d->lf / wheelbase;
    double alpha_f = delta - atan((vy + d->lf * r) / vx);
    double alpha_r = -atan((vy - d->lr * r) / vx);
    double fyf = tyre_force(alpha_f, d->Cf, d->shape, d->mu * fzf);
    double fyr = tyre_force(alpha_r, d->Cr, d->shape, d->mu * fzr);
    double cmd = fmax(-d->delta_max, fmin(d->delta_max, d->steer_cmd));
    d->speed = vx;
    d->curvature = kappa;
    d->der_lateral_velocity = (fyf * cos(delta) + fyr) / d->m - vx * r;
    d->der_yaw_rate = (d->lf * fyf * cos(delta) - d->lr * fyr) / d->Iz;
    d->der_lateral_error = vy * cos(e_psi) + vx * sin(e_psi);
    d->der_distance = (vx * cos(e_psi) - vy * sin(e_psi)) / (1.0 - kappa * e_y);
    d->der_heading_error = r - kappa * d->der_distance;
    d->der_steer_angle = d->steer_rate_max * tanh((cmd - delta) / (d->steer_tau * d->steer_rate_max));
    d->lateral_accel = d->der_lateral_velocity + vx * r;
}

void model_event_update(FmuInstance* inst, FmuEventResult* ev) {
    (void)inst;
    (void)ev;   /* no events */
}

FmuStatus model_do_step(FmuInstance* inst, double h) {
    fmu_rk4(inst, h, inst->s.d.solver_step);
    return FMU_OK;
}
