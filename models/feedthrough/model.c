/* Feedthrough: y takes u's value at the end of each doStep. No states, no events, no parameters:
 * stepping it costs what the FMI calls themselves cost, the floor for an importer's overhead. */
#include "fmu_core.h"

FmuStatus model_initialize(FmuInstance* inst) {
    inst->s.d.y = inst->s.d.u;
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
    (void)h;
    inst->s.d.y = inst->s.d.u;
    return FMU_OK;
}
