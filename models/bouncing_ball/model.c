/* Bouncing ball: dh/dt = v, dv/dt = -g; when h reaches 0 while falling, v <- -e v.
 * Co-simulation locates each contact analytically (free flight is a parabola, so the contact time is
 * the positive root of h + v t - g t^2 / 2 = 0) and is therefore exact up to rounding. */
#include "fmu_core.h"

#include <math.h>

#define MAX_BOUNCES_PER_STEP 100000

FmuStatus model_initialize(FmuInstance* inst) {
    ModelData* d = &inst->s.d;
    if (!(d->g > 0.0) || !(d->e >= 0.0 && d->e <= 1.0) || !(d->h0 >= 0.0) || !(d->v_min >= 0.0)) {
        fmu_log_error(inst, "bouncing_ball: need g > 0, 0 <= e <= 1, h0 >= 0 and v_min >= 0, got g = %g m/s2, "
                      "e = %g, h0 = %g m, v_min = %g m/s", d->g, d->e, d->h0, d->v_min);
        return FMU_ERROR;
    }
    d->h = d->h0;
    d->v = 0.0;
    d->bounces = 0;
    d->at_rest = false;
    return FMU_OK;
}

void model_evaluate(FmuInstance* inst) {
    ModelData* d = &inst->s.d;
    d->der_h = d->at_rest ? 0.0 : d->v;
    d->der_v = d->at_rest ? 0.0 : -d->g;
}

/* The ball touches the floor: reverse and damp the velocity, or let it rest. */
static void bounce(FmuInstance* inst) {
    ModelData* d = &inst->s.d;
    d->h = 0.0;
    d->v = -d->e * d->v;
    d->bounces += 1;
    if (d->v <= d->v_min) {
        d->v = 0.0;
        d->at_rest = true;
    }
    fmu_log_event(inst, "bouncing_ball: bounce %d at t = %.17g s, rebound speed %g m/s%s", (int)d->bounces,
                  inst->s.time, d->v, d->at_rest ? " (ball at rest)" : "");
}

void model_event_update(FmuInstance* inst, FmuEventResult* ev) {
    ModelData* d = &inst->s.d;
    if (!d->at_rest && d->h <= 0.0 && d->v < 0.0) {
        bounce(inst);
        ev->values_of_continuous_states_changed = true;
    }
}

static void fly(ModelData* d, double t) {
    d->h += d->v * t - 0.5 * d->g * t * t;
    d->v -= d->g * t;
}

FmuStatus model_do_step(FmuInstance* inst, double h) {
    ModelData* d = &inst->s.d;
    const double t_end = inst->s.time + h;
    double remaining = h;
    for (int k = 0; k < MAX_BOUNCES_PER_STEP && !d->at_rest && remaining > 0.0; k++) {
        const double height = d->h > 0.0 ? d->h : 0.0;
        const double contact = (d->v + sqrt(d->v * d->v + 2.0 * d->g * height)) / d->g;
        if (contact >= remaining) {
            fly(d, remaining);
            break;
        }
        fly(d, contact);
        remaining -= contact;
        inst->s.time = t_end - remaining;
        bounce(inst);
    }
    if (d->h < 0.0) d->h = 0.0;   /* rounding right at a contact */
    if (d->at_rest) {
        d->h = 0.0;
        d->v = 0.0;
    }
    return FMU_OK;
}
