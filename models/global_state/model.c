/* Global state: the integral lives in a static variable, not in the instance, as in tool exports
 * that keep solver or table state in globals. One instance per process is right; a second instance
 * in the same process resets and adds to the first one's integral. The model says so in its
 * description (canBeInstantiatedOnlyOncePerProcess), which the importer must honour. */
#include "fmu_core.h"

static double g_integral = 0.0;   /* shared by every instance loaded from this library */

FmuStatus model_initialize(FmuInstance* inst) {
    g_integral = 0.0;
    inst->s.d.y = 0.0;
    return FMU_OK;
}

void model_evaluate(FmuInstance* inst) {
    (void)inst;   /* y changes only in doStep */
}

void model_event_update(FmuInstance* inst, FmuEventResult* ev) {
    (void)inst;
    (void)ev;   /* co-simulation only */
}

FmuStatus model_do_step(FmuInstance* inst, double h) {
    g_integral += inst->s.d.gain * inst->s.d.u * h;
    inst->s.d.y = g_integral;
    return FMU_OK;
}
