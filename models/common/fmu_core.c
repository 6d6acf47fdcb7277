/* Life cycle, mode checks and logging of an fmu-bridge example model instance. */
#include "fmu_core.h"

#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

const char* const FMU_LOG_CATEGORY_NAMES[LOG_N_CATEGORIES] = {"logEvents", "logStatusWarning", "logStatusError"};

static const char* const MODE_NAMES[] = {
    "instantiated", "initialization mode", "step mode", "event mode", "continuous-time mode",
    "terminated", "error (after a failed call; reset or free the instance)"};

void fmu_log(FmuInstance* inst, FmuStatus status, FmuLogCategory category, const char* fmt, ...) {
    if (inst == NULL || inst->emit == NULL) return;
    /* errors are always reported; other categories only when debug logging enabled them */
    if (category != LOG_STATUS_ERROR && !(inst->logging_on && inst->categories[category])) return;
    char message[1024];
    va_list args;
    va_start(args, fmt);
    vsnprintf(message, sizeof message, fmt, args);
    va_end(args);
    if (inst->fmi_version >= 3) {
        inst->emit(inst, status, FMU_LOG_CATEGORY_NAMES[category], message);
        return;
    }
    /* FMI 1.0/2.0 loggers take a printf format: a literal '%' must arrive as "%%" */
    char escaped[2 * sizeof message];
    size_t n = 0;
    for (const char* p = message; *p != '\0' && n + 2 < sizeof escaped; p++) {
        if (*p == '%') escaped[n++] = '%';
        escaped[n++] = *p;
    }
    escaped[n] = '\0';
    inst->emit(inst, status, FMU_LOG_CATEGORY_NAMES[category], escaped);
}

bool fmu_check_mode(FmuInstance* inst, unsigned allowed, const char* fn) {
    if (allowed & FMU_MODE_BIT(inst->s.mode)) return true;
    fmu_log_error(inst, "%s is not allowed in %s", fn, MODE_NAMES[inst->s.mode]);
    return false;
}

bool fmu_check_interface(FmuInstance* inst, FmuInterface required, const char* fn) {
    if (inst->interface == required) return true;
    fmu_log_error(inst, "%s is a %s function, but this instance was instantiated for %s", fn,
                  required == FMU_ME ? "model-exchange" : "co-simulation",
                  inst->interface == FMU_ME ? "model exchange" : "co-simulation");
    return false;
}

FmuStatus fmu_unsupported(FmuInstance* inst, const char* fn, const char* what) {
    fmu_log_error(inst, "%s is not supported: %s (see the capability flags in modelDescription.xml)", fn, what);
    return FMU_ERROR;
}

bool fmu_check_count(FmuInstance* inst, const char* fn, size_t given, size_t expected, const char* what) {
    if (given == expected) return true;
    fmu_log_error(inst, "%s: expected %zu %s, got %zu", fn, expected, what, given);
    return false;
}

static bool apply_start_value(ModelData* d, const FmuVariable* v) {
    void* p = (char*)d + v->offset;
    if (v->n_elements > 0) { /* arrays: Float64 only (the generator rejects others) */
        for (size_t k = 0; k < v->n_elements; k++) {
            ((double*)p)[k] = v->start_array != NULL ? v->start_array[k] : v->start_real;
        }
        return true;
    }
    switch (v->type) {
        case T_FLOAT32: *(float*)p = (float)v->start_real; break;
        case T_FLOAT64: *(double*)p = v->start_real; break;
        case T_INT8: *(int8_t*)p = (int8_t)v->start_int; break;
        case T_UINT8: *(uint8_t*)p = (uint8_t)v->start_uint; break;
        case T_INT16: *(int16_t*)p = (int16_t)v->start_int; break;
        case T_UINT16: *(uint16_t*)p = (uint16_t)v->start_uint; break;
        case T_INT32: *(int32_t*)p = (int32_t)v->start_int; break;
        case T_UINT32: *(uint32_t*)p = (uint32_t)v->start_uint; break;
        case T_INT64: *(int64_t*)p = v->start_int; break;
        case T_UINT64: *(uint64_t*)p = v->start_uint; break;
        case T_BOOLEAN: *(bool*)p = v->start_int != 0; break;
        case T_CLOCK: *(bool*)p = false; break;
        case T_ENUMERATION: *(int64_t*)p = v->start_int; break;
        case T_BINARY: return fmu_binary_assign((FmuBinary*)p, v->start_binary, v->start_size);
        case T_STRING: {
            const char* text = v->start_string != NULL ? v->start_string : "";
            char* copy = malloc(strlen(text) + 1);
            if (copy == NULL) return false;
            strcpy(copy, text);
            *(char**)p = copy;
            break;
        }
        case T_NONE: break;
    }
    return true;
}

/* Start values from the variable table; strings and binaries become instance-owned copies. */
static FmuStatus apply_defaults(FmuInstance* inst, const char* fn) {
    fmu_free_owned(&inst->s.d);
    memset(&inst->s, 0, sizeof inst->s);
    for (size_t vr = 0; vr < MODEL_N_VARS; vr++) {
        const FmuVariable* v = &MODEL_VARIABLES[vr];
        if (v->causality == C_INDEPENDENT || v->type == T_NONE) continue;
        if (!apply_start_value(&inst->s.d, v)) {
            fmu_log_error(inst, "%s: out of memory while copying the start value of %s", fn, v->name);
            return FMU_FATAL;
        }
    }
    inst->s.mode = MODE_INSTANTIATED;
    inst->dirty = true;
    return FMU_OK;
}

FmuStatus fmu_setup(FmuInstance* inst, const char* fn, const char* name, const char* token,
                    FmuInterface requested, bool logging_on) {
    inst->logging_on = logging_on;
    for (int c = 0; c < LOG_N_CATEGORIES; c++) inst->categories[c] = true;
    const char* instance_name = name != NULL ? name : "";
    inst->name = malloc(strlen(instance_name) + 1);
    if (inst->name == NULL) return FMU_FATAL;
    strcpy(inst->name, instance_name);
    if (token == NULL || strcmp(token, INSTANTIATION_TOKEN) != 0) {
        fmu_log_error(inst, "%s: instantiation token/GUID %s does not match %s of this binary; "
                      "the modelDescription.xml and the binary come from different builds",
                      fn, token != NULL ? token : "(null)", INSTANTIATION_TOKEN);
        return FMU_ERROR;
    }
    if (requested != MODEL_INTERFACE) {
        fmu_log_error(inst, "%s: this binary implements %s only; use the %s variant of " MODEL_NAME, fn,
                      MODEL_INTERFACE == FMU_CS ? "co-simulation" : "model exchange",
                      requested == FMU_CS ? "co-simulation" : "model-exchange");
        return FMU_ERROR;
    }
    inst->interface = requested;
    return apply_defaults(inst, fn);
}

void fmu_teardown(FmuInstance* inst) {
    fmu_free_owned(&inst->s.d);
    free(inst->name);
    inst->name = NULL;
}

FmuStatus fmu_reset(FmuInstance* inst, const char* fn) {
    return apply_defaults(inst, fn);
}

FmuStatus fmu_enter_initialization(FmuInstance* inst, const char* fn, double start_time) {
    if (!fmu_check_mode(inst, FMU_MODE_BIT(MODE_INSTANTIATED), fn)) return FMU_ERROR;
    inst->s.time = start_time;
    inst->s.mode = MODE_INITIALIZATION;
    inst->dirty = true;
    return FMU_OK;
}

FmuStatus fmu_exit_initialization(FmuInstance* inst, const char* fn) {
    if (!fmu_check_mode(inst, FMU_MODE_BIT(MODE_INITIALIZATION), fn)) return FMU_ERROR;
    FmuStatus status = model_initialize(inst);
    inst->dirty = true;
    if (status >= FMU_ERROR) {
        inst->s.mode = MODE_ERROR;
        return status;
    }
    inst->s.mode = inst->interface == FMU_CS ? MODE_STEP : MODE_EVENT;
    return status;
}

FmuStatus fmu_terminate(FmuInstance* inst, const char* fn) {
    unsigned allowed = FMU_MODE_BIT(MODE_STEP) | FMU_MODE_BIT(MODE_EVENT) | FMU_MODE_BIT(MODE_CONTINUOUS);
    if (!fmu_check_mode(inst, allowed, fn)) return FMU_ERROR;
    inst->s.mode = MODE_TERMINATED;
    return FMU_OK;
}

FmuStatus fmu_set_debug_logging(FmuInstance* inst, const char* fn, bool on, size_t n, const char* const names[]) {
    inst->logging_on = on;
    if (n == 0) {
        for (int c = 0; c < LOG_N_CATEGORIES; c++) inst->categories[c] = on;
        return FMU_OK;
    }
    for (size_t k = 0; k < n; k++) {
        int found = -1;
        for (int c = 0; c < LOG_N_CATEGORIES; c++) {
            if (names[k] != NULL && strcmp(names[k], FMU_LOG_CATEGORY_NAMES[c]) == 0) found = c;
        }
        if (found < 0) {
            fmu_log_error(inst, "%s: unknown log category %s; known: logEvents, logStatusWarning, logStatusError",
                          fn, names[k] != NULL ? names[k] : "(null)");
            return FMU_ERROR;
        }
        inst->categories[found] = on;
    }
    return FMU_OK;
}
