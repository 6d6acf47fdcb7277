/* Mass on a spring, a harmonic oscillator with Modelica-style variable names (see model.json for the
 * names; the C fields are the identifiers derived from them, e.g. body.frame_a.r_0[1] is
 * body_frame_a_r_0_1 and 'force in N' is force_in_N):
 *   der(body.s) = body.v,  body.m der(body.v) = -spring.c body.s + 'force in N'. */
#include "fmu_core.h"

#define MAX_SUBSTEP 1e-3 /* RK4 substep of co-simulation in s */

FmuStatus model_initialize(FmuInstance* inst) {
    ModelData* d = &inst->s.d;
    if (!(d->body_m > 0.0) || !(d->spring_c > 0.0)) {
        fmu_log_error(inst, "modelica_names: body.m and spring.c must be > 0, got %g kg and %g N/m; "
                      "set positive values before initialization", d->body_m, d->spring_c);
        return FMU_ERROR;
    }
    d->body_s = d->body_s_start;
    d->body_v = d->body_v_start;
    return FMU_OK;
}

void model_evaluate(FmuInstance* inst) {
    ModelData* d = &inst->s.d;
    d->f_spring = -d->spring_c * d->body_s;
    d->der_body_s = d->body_v;
    d->der_body_v = (d->force_in_N + d->f_spring) / d->body_m;
    d->body_frame_a_r_0_1 = d->body_s;
    d->energy_J_total = 0.5 * d->body_m * d->body_v * d->body_v + 0.5 * d->spring_c * d->body_s * d->body_s;
}

void model_event_update(FmuInstance* inst, FmuEventResult* ev) {
    (void)inst;
    (void)ev;
}

FmuStatus model_do_step(FmuInstance* inst, double h) {
    fmu_rk4(inst, h, MAX_SUBSTEP);
    return FMU_OK;
}
