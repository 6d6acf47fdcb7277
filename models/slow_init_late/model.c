/* slow_init's thermal mass (the same equations; this model's model.json makes it refuse a state
 * before initialisation). Thermal mass with a slow initialisation:
 *   C dT/dt = base_power + power - k (T - T_amb) - r (T - T_amb)^3
 * At the exit of initialisation mode it relaxes T from T_amb towards the equilibrium under the base
 * load by warmup_steps explicit Euler steps in pseudo time (step C / (4 k), stable for the linear
 * part), which is what makes initialisation slow and a saved state worth having. */
#include "fmu_core.h"

static double heat_flow(const ModelData* d, double T, double power) {
    const double dT = T - d->T_amb;
    return d->base_power + power - d->k * dT - d->r * dT * dT * dT;
}

FmuStatus model_initialize(FmuInstance* inst) {
    ModelData* d = &inst->s.d;
    if (!(d->C > 0.0) || !(d->k > 0.0) || !(d->r >= 0.0) || !(d->solver_step > 0.0) || d->warmup_steps < 0) {
        fmu_log_error(inst, "slow_init: need C, k, solver_step > 0 and r, warmup_steps >= 0, got C = %g J/K, "
                      "k = %g W/K, r = %g, solver_step = %g s, warmup_steps = %d", d->C, d->k, d->r,
                      d->solver_step, (int)d->warmup_steps);
        return FMU_ERROR;
    }
    const double tau = 0.25 / d->k; /* pseudo-time step over C */
    double T = d->T_amb;
    for (int32_t i = 0; i < d->warmup_steps; i++) T += tau * heat_flow(d, T, 0.0);
    d->T_init = T;
    d->T = T;
    return FMU_OK;
}

void model_evaluate(FmuInstance* inst) {
    ModelData* d = &inst->s.d;
    d->der_T = heat_flow(d, d->T, d->power) / d->C;
}

void model_event_update(FmuInstance* inst, FmuEventResult* ev) {
    (void)inst;
    (void)ev; /* no events */
}

FmuStatus model_do_step(FmuInstance* inst, double h) {
    fmu_rk4(inst, h, inst->s.d.solver_step);
    return FMU_OK;
}
