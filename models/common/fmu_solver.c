/* Co-simulation stepping (with a classic RK4 helper) and the model-exchange state interface. */
#include "fmu_core.h"

#include <math.h>
#include <string.h>

#define STEP_MODES (FMU_MODE_BIT(MODE_STEP))
#define ME_STATE_MODES (FMU_MODE_BIT(MODE_EVENT) | FMU_MODE_BIT(MODE_CONTINUOUS))
#define ME_READ_MODES (ME_STATE_MODES | FMU_MODE_BIT(MODE_INITIALIZATION) | FMU_MODE_BIT(MODE_TERMINATED))

static double field(const FmuInstance* inst, size_t offset) {
    return *(const double*)((const char*)&inst->s.d + offset);
}

static void set_field(FmuInstance* inst, size_t offset, double value) {
    *(double*)((char*)&inst->s.d + offset) = value;
}

static void refresh(FmuInstance* inst) {
    if (!inst->dirty) return;
    model_evaluate(inst);
    inst->dirty = false;
}

FmuStatus fmu_do_step(FmuInstance* inst, const char* fn, double t, double h) {
    if (!fmu_check_interface(inst, FMU_CS, fn) || !fmu_check_mode(inst, STEP_MODES, fn)) return FMU_ERROR;
    if (inst->s.terminate_requested) {
        fmu_log_error(inst, "%s: the model requested termination at t = %.17g s; reset the instance or "
                      "restore an earlier FMU state before stepping again", fn, inst->s.time);
        return FMU_ERROR;
    }
    if (!(h > 0.0) || h > MODEL_MAX_STEP) {
        fmu_log_error(inst, "%s: communication step size %.17g s is outside the allowed range "
                      "0 < step <= %g s", fn, h, MODEL_MAX_STEP);
        return FMU_ERROR;
    }
    inst->s.time = t;
    refresh(inst);
    FmuStatus status = model_do_step(inst, h);
    inst->dirty = true;
    if (status >= FMU_ERROR) {
        inst->s.mode = MODE_ERROR;
        return status;
    }
    inst->s.time = t + h;
    return status;
}

/* Number of equal substeps: ceil(h / max_substep), with the ratio rounded to 1e-9 first so that
 * h = 0.02, max_substep = 1e-3 gives 20 substeps, not 21. */
static long substeps(double h, double max_substep) {
    if (!(max_substep > 0.0) || max_substep >= h) return 1;
    return (long)ceil(h / max_substep - 1e-9);
}

static void derivatives_at(FmuInstance* inst, double t, const double x[], double dx[]) {
    inst->s.time = t;
    for (size_t k = 0; k < MODEL_NX; k++) set_field(inst, MODEL_STATE_OFFSETS[k], x[k]);
    model_evaluate(inst);
    for (size_t k = 0; k < MODEL_NX; k++) dx[k] = field(inst, MODEL_DERIVATIVE_OFFSETS[k]);
}

void fmu_rk4(FmuInstance* inst, double h, double max_substep) {
    double x[MODEL_NX_ALLOC], xs[MODEL_NX_ALLOC];
    double k1[MODEL_NX_ALLOC], k2[MODEL_NX_ALLOC], k3[MODEL_NX_ALLOC], k4[MODEL_NX_ALLOC];
    const double t0 = inst->s.time;
    const long n = substeps(h, max_substep);
    const double dt = h / (double)n;
    for (size_t k = 0; k < MODEL_NX; k++) x[k] = field(inst, MODEL_STATE_OFFSETS[k]);
    for (long j = 0; j < n; j++) {
        const double t = t0 + (double)j * dt;
        derivatives_at(inst, t, x, k1);
        for (size_t k = 0; k < MODEL_NX; k++) xs[k] = x[k] + 0.5 * dt * k1[k];
        derivatives_at(inst, t + 0.5 * dt, xs, k2);
        for (size_t k = 0; k < MODEL_NX; k++) xs[k] = x[k] + 0.5 * dt * k2[k];
        derivatives_at(inst, t + 0.5 * dt, xs, k3);
        for (size_t k = 0; k < MODEL_NX; k++) xs[k] = x[k] + dt * k3[k];
        derivatives_at(inst, t + dt, xs, k4);
        for (size_t k = 0; k < MODEL_NX; k++) x[k] += dt / 6.0 * (k1[k] + 2.0 * k2[k] + 2.0 * k3[k] + k4[k]);
    }
    inst->s.time = t0 + h;
    for (size_t k = 0; k < MODEL_NX; k++) set_field(inst, MODEL_STATE_OFFSETS[k], x[k]);
    inst->dirty = true;
}

FmuStatus fmu_set_time(FmuInstance* inst, const char* fn, double time) {
    if (!fmu_check_interface(inst, FMU_ME, fn) || !fmu_check_mode(inst, ME_STATE_MODES, fn)) return FMU_ERROR;
    inst->s.time = time;
    inst->dirty = true;
    return FMU_OK;
}

FmuStatus fmu_enter_event_mode(FmuInstance* inst, const char* fn) {
    if (!fmu_check_interface(inst, FMU_ME, fn) || !fmu_check_mode(inst, ME_STATE_MODES, fn)) return FMU_ERROR;
    inst->s.mode = MODE_EVENT;
    return FMU_OK;
}

FmuStatus fmu_enter_continuous_mode(FmuInstance* inst, const char* fn) {
    if (!fmu_check_interface(inst, FMU_ME, fn) || !fmu_check_mode(inst, FMU_MODE_BIT(MODE_EVENT), fn)) {
        return FMU_ERROR;
    }
    inst->s.mode = MODE_CONTINUOUS;
    return FMU_OK;
}

FmuStatus fmu_event_update(FmuInstance* inst, const char* fn, FmuEventResult* ev) {
    memset(ev, 0, sizeof *ev);
    if (!fmu_check_interface(inst, FMU_ME, fn) || !fmu_check_mode(inst, FMU_MODE_BIT(MODE_EVENT), fn)) {
        return FMU_ERROR;
    }
    refresh(inst);
    model_event_update(inst, ev);
    inst->dirty = true;
    if (ev->terminate_simulation) inst->s.terminate_requested = true;
    return FMU_OK;
}

static bool me_access(FmuInstance* inst, const char* fn, unsigned modes, size_t given, size_t expected,
                      const char* what) {
    return fmu_check_interface(inst, FMU_ME, fn) && fmu_check_mode(inst, modes, fn) &&
           fmu_check_count(inst, fn, given, expected, what);
}

FmuStatus fmu_get_states(FmuInstance* inst, const char* fn, double x[], size_t nx) {
    if (!me_access(inst, fn, ME_READ_MODES, nx, MODEL_NX, "continuous states")) return FMU_ERROR;
    for (size_t k = 0; k < MODEL_NX; k++) x[k] = field(inst, MODEL_STATE_OFFSETS[k]);
    return FMU_OK;
}

FmuStatus fmu_set_states(FmuInstance* inst, const char* fn, const double x[], size_t nx) {
    if (!me_access(inst, fn, ME_STATE_MODES, nx, MODEL_NX, "continuous states")) return FMU_ERROR;
    for (size_t k = 0; k < MODEL_NX; k++) set_field(inst, MODEL_STATE_OFFSETS[k], x[k]);
    inst->dirty = true;
    return FMU_OK;
}

FmuStatus fmu_get_derivatives(FmuInstance* inst, const char* fn, double dx[], size_t nx) {
    if (!me_access(inst, fn, ME_READ_MODES, nx, MODEL_NX, "state derivatives")) return FMU_ERROR;
    refresh(inst);
    for (size_t k = 0; k < MODEL_NX; k++) dx[k] = field(inst, MODEL_DERIVATIVE_OFFSETS[k]);
    return FMU_OK;
}

FmuStatus fmu_get_nominals(FmuInstance* inst, const char* fn, double nominals[], size_t nx) {
    unsigned modes = ME_READ_MODES | FMU_MODE_BIT(MODE_INSTANTIATED);
    if (!me_access(inst, fn, modes, nx, MODEL_NX, "state nominals")) return FMU_ERROR;
    for (size_t k = 0; k < MODEL_NX; k++) nominals[k] = MODEL_STATE_NOMINALS[k];
    return FMU_OK;
}

FmuStatus fmu_get_event_indicators(FmuInstance* inst, const char* fn, double z[], size_t nz) {
    if (!me_access(inst, fn, ME_READ_MODES, nz, MODEL_NZ, "event indicators")) return FMU_ERROR;
    refresh(inst);
    for (size_t k = 0; k < MODEL_NZ; k++) z[k] = field(inst, MODEL_EVENT_INDICATOR_OFFSETS[k]);
    return FMU_OK;
}
