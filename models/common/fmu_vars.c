/* Typed access to the generated variable table, and FMU state snapshots. */
#include "fmu_core.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

static const char* type_name(const FmuInstance* inst, FmuType type) {
    static const char* const fmi3_names[] = {
        "none", "Float32", "Float64", "Int8", "UInt8", "Int16", "UInt16", "Int32", "UInt32",
        "Int64", "UInt64", "Boolean", "String", "Enumeration", "Binary", "Clock"};
    if (inst->fmi_version < 3 && type == T_FLOAT64) return "Real";
    if (inst->fmi_version < 3 && type == T_INT32) return "Integer";
    return fmi3_names[type];
}

static const char* causality_name(FmuCausality causality) {
    static const char* const names[] = {
        "a parameter", "a calculated parameter", "an input", "an output", "a local variable",
        "the independent variable"};
    return names[causality];
}

static const FmuVariable* find_variable(FmuInstance* inst, const char* fn, unsigned type_mask, unsigned vr) {
    if (vr >= MODEL_N_VARS || MODEL_VARIABLES[vr].type == T_NONE || !MODEL_VARIABLES[vr].exposed) {
        fmu_log_error(inst, "%s: value reference %u is not a variable of %s; see modelDescription.xml",
                      fn, vr, MODEL_NAME);
        return NULL;
    }
    const FmuVariable* v = &MODEL_VARIABLES[vr];
    if (!(type_mask & FMU_TYPE_BIT(v->type))) {
        fmu_log_error(inst, "%s cannot access %s (value reference %u): its type is %s", fn, v->name, vr,
                      type_name(inst, v->type));
        return NULL;
    }
    return v;
}

/* Bytes per element of each type's storage (arrays are C arrays of these). */
static size_t element_size(FmuType type) {
    switch (type) {
        case T_FLOAT32: return sizeof(float);
        case T_INT8: case T_UINT8: return 1;
        case T_INT16: case T_UINT16: return 2;
        case T_INT32: case T_UINT32: return 4;
        case T_BOOLEAN: case T_CLOCK: return sizeof(bool);
        case T_STRING: return sizeof(char*);
        case T_BINARY: return sizeof(FmuBinary);
        default: return 8; /* Float64, Int64, UInt64, Enumeration */
    }
}

static void* field(const ModelData* d, const FmuVariable* v, size_t index) {
    return (char*)d + v->offset + index * element_size(v->type);
}

static void read_field(const FmuInstance* inst, const FmuVariable* v, size_t index, FmuValue* out) {
    const void* p = field(&inst->s.d, v, index);
    switch (v->type) {
        case T_FLOAT32: out->f = *(const float*)p; break;
        case T_FLOAT64: out->f = *(const double*)p; break;
        case T_INT8: out->i = *(const int8_t*)p; break;
        case T_UINT8: out->u = *(const uint8_t*)p; break;
        case T_INT16: out->i = *(const int16_t*)p; break;
        case T_UINT16: out->u = *(const uint16_t*)p; break;
        case T_INT32: out->i = *(const int32_t*)p; break;
        case T_UINT32: out->u = *(const uint32_t*)p; break;
        case T_INT64: out->i = *(const int64_t*)p; break;
        case T_UINT64: out->u = *(const uint64_t*)p; break;
        case T_BOOLEAN: case T_CLOCK: out->b = *(const bool*)p; break;
        case T_ENUMERATION: out->i = *(const int64_t*)p; break;
        case T_STRING: out->s = *(char* const*)p; break;
        case T_BINARY:
            out->bin.data = ((const FmuBinary*)p)->data;
            out->bin.size = ((const FmuBinary*)p)->size;
            break;
        case T_NONE: break;
    }
}

bool fmu_binary_assign(FmuBinary* dst, const uint8_t* data, size_t size) {
    uint8_t* copy = malloc(size > 0 ? size : 1);
    if (copy == NULL) return false;
    if (size > 0) memcpy(copy, data, size);
    free(dst->data);
    dst->data = copy;
    dst->size = size;
    return true;
}

static bool write_field(FmuInstance* inst, const FmuVariable* v, size_t index, const FmuValue* in) {
    void* p = field(&inst->s.d, v, index);
    switch (v->type) {
        case T_FLOAT32: *(float*)p = (float)in->f; break;
        case T_FLOAT64: *(double*)p = in->f; break;
        case T_INT8: *(int8_t*)p = (int8_t)in->i; break;
        case T_UINT8: *(uint8_t*)p = (uint8_t)in->u; break;
        case T_INT16: *(int16_t*)p = (int16_t)in->i; break;
        case T_UINT16: *(uint16_t*)p = (uint16_t)in->u; break;
        case T_INT32: *(int32_t*)p = (int32_t)in->i; break;
        case T_UINT32: *(uint32_t*)p = (uint32_t)in->u; break;
        case T_INT64: *(int64_t*)p = in->i; break;
        case T_UINT64: *(uint64_t*)p = in->u; break;
        case T_BOOLEAN: case T_CLOCK: *(bool*)p = in->b; break;
        case T_ENUMERATION: *(int64_t*)p = in->i; break;
        case T_STRING: {
            char* copy = malloc(strlen(in->s) + 1);
            if (copy == NULL) return false;
            strcpy(copy, in->s);
            free(*(char**)p);
            *(char**)p = copy;
            break;
        }
        case T_BINARY: return fmu_binary_assign((FmuBinary*)p, in->bin.data, in->bin.size);
        case T_NONE: break;
    }
    return true;
}

size_t fmu_value_count(unsigned vr) {
    if (vr >= MODEL_N_VARS || MODEL_VARIABLES[vr].n_elements == 0) return 1;
    return MODEL_VARIABLES[vr].n_elements;
}

FmuStatus fmu_get_element(FmuInstance* inst, const char* fn, unsigned type_mask, unsigned vr, size_t index,
                          FmuValue* out) {
    const FmuVariable* v = find_variable(inst, fn, type_mask, vr);
    if (v == NULL) return FMU_ERROR;
    if (v->causality == C_INDEPENDENT) {
        out->f = inst->s.time;
        return FMU_OK;
    }
    if (inst->dirty) {
        model_evaluate(inst);
        inst->dirty = false;
    }
    read_field(inst, v, index, out);
    return FMU_OK;
}

FmuStatus fmu_get(FmuInstance* inst, const char* fn, unsigned type_mask, unsigned vr, FmuValue* out) {
    return fmu_get_element(inst, fn, type_mask, vr, 0, out);
}

/* Which modes may set a variable: FMI 2.0/3.0 rules, FMI 1.0 treats every parameter as fixed. */
static unsigned settable_modes(const FmuInstance* inst, const FmuVariable* v) {
    unsigned before_init = FMU_MODE_BIT(MODE_INSTANTIATED) | FMU_MODE_BIT(MODE_INITIALIZATION);
    if (v->causality == C_INPUT) {
        /* FMI 2.0/3.0 model exchange: discrete inputs change only in event mode (FMI 1.0 has no modes). */
        unsigned running = FMU_MODE_BIT(MODE_STEP) | FMU_MODE_BIT(MODE_EVENT);
        if (v->variability == V_CONTINUOUS || inst->fmi_version == 1) running |= FMU_MODE_BIT(MODE_CONTINUOUS);
        return before_init | running;
    }
    if (v->variability == V_TUNABLE && inst->fmi_version >= 2) {
        return before_init | FMU_MODE_BIT(MODE_STEP) | FMU_MODE_BIT(MODE_EVENT);
    }
    return before_init;
}

static FmuStatus check_settable(FmuInstance* inst, const char* fn, const FmuVariable* v, unsigned vr) {
    if (v->variability == V_CONSTANT || (v->causality != C_INPUT && v->causality != C_PARAMETER)) {
        fmu_log_error(inst, "%s: %s (value reference %u) is %s and cannot be set; only inputs and "
                      "non-constant parameters can", fn, v->name, vr,
                      v->variability == V_CONSTANT ? "a constant" : causality_name(v->causality));
        return FMU_ERROR;
    }
    if (settable_modes(inst, v) & FMU_MODE_BIT(inst->s.mode)) return FMU_OK;
    if (v->causality == C_PARAMETER && v->variability == V_TUNABLE && inst->fmi_version >= 2) {
        fmu_log_error(inst, "%s: tunable parameter %s can only be set before initialization ends or in step or "
                      "event mode", fn, v->name);
    } else if (v->causality == C_PARAMETER) {
        fmu_log_error(inst, "%s: fixed parameter %s can only be set before initialization ends; reset the "
                      "instance to change it", fn, v->name);
    } else if (inst->s.mode == MODE_CONTINUOUS) {
        fmu_log_error(inst, "%s: discrete input %s can only be set in event mode (call EnterEventMode first)",
                      fn, v->name);
    } else {
        fmu_log_error(inst, "%s: input %s cannot be set after the instance terminated or failed", fn, v->name);
    }
    return FMU_ERROR;
}

static FmuStatus check_value(FmuInstance* inst, const char* fn, const FmuVariable* v, const FmuValue* in) {
    if (v->type == T_STRING && in->s == NULL) {
        fmu_log_error(inst, "%s: NULL is not a valid value for String %s; pass an empty string", fn, v->name);
        return FMU_ERROR;
    }
    if (v->type == T_BINARY && in->bin.data == NULL && in->bin.size > 0) {
        fmu_log_error(inst, "%s: NULL data with size %zu for Binary %s; pass a valid pointer", fn,
                      in->bin.size, v->name);
        return FMU_ERROR;
    }
    if (!v->has_min && !v->has_max) return FMU_OK;
    double x;
    if (v->type == T_FLOAT32 || v->type == T_FLOAT64) x = in->f;
    else if (v->type == T_UINT8 || v->type == T_UINT16 || v->type == T_UINT32 || v->type == T_UINT64) x = (double)in->u;
    else x = (double)in->i;
    bool outside = (v->has_min && x < v->min) || (v->has_max && x > v->max);
    if (!outside) return FMU_OK;
    if (v->type == T_ENUMERATION) {
        fmu_log_error(inst, "%s: %s = %g is not an item of its enumeration type (items %g..%g)", fn, v->name, x,
                      v->min, v->max);
        return FMU_ERROR;
    }
    /* min/max are declarations: the value is used as given, never clamped */
    fmu_log_warning(inst, "%s: %s = %g is outside its declared range [%g, %g]; the value is used unchanged",
                    fn, v->name, x, v->has_min ? v->min : -HUGE_VAL, v->has_max ? v->max : HUGE_VAL);
    return FMU_WARNING;
}

FmuStatus fmu_set_element(FmuInstance* inst, const char* fn, unsigned type_mask, unsigned vr, size_t index,
                          const FmuValue* in) {
    const FmuVariable* v = find_variable(inst, fn, type_mask, vr);
    if (v == NULL) return FMU_ERROR;
    FmuStatus status = check_settable(inst, fn, v, vr);
    if (status != FMU_OK) return status;
    status = check_value(inst, fn, v, in);
    if (status >= FMU_ERROR) return status;
    if (!write_field(inst, v, index, in)) {
        fmu_log_error(inst, "%s: out of memory while copying the value of %s", fn, v->name);
        return FMU_FATAL;
    }
    inst->dirty = true;
    return status;
}

FmuStatus fmu_set(FmuInstance* inst, const char* fn, unsigned type_mask, unsigned vr, const FmuValue* in) {
    return fmu_set_element(inst, fn, type_mask, vr, 0, in);
}

/* Deep copy of the instance-owned strings and binaries; dst's fields are overwritten, not freed. */
static bool copy_owned(ModelData* dst, const ModelData* src) {
    bool ok = true;
    for (size_t vr = 0; vr < MODEL_N_VARS; vr++) {
        const FmuVariable* v = &MODEL_VARIABLES[vr];
        if (v->type == T_BINARY) {
            FmuBinary* to = field(dst, v, 0);
            const FmuBinary* from = field(src, v, 0);
            to->data = NULL;
            ok = fmu_binary_assign(to, from->data, from->size) && ok;
            continue;
        }
        if (v->type != T_STRING) continue;
        const char* text = *(char* const*)field(src, v, 0);
        char* copy = malloc(strlen(text) + 1);
        if (copy != NULL) strcpy(copy, text);
        else ok = false;
        *(char**)field(dst, v, 0) = copy;
    }
    return ok;
}

void fmu_free_owned(ModelData* d) {
    for (size_t vr = 0; vr < MODEL_N_VARS; vr++) {
        const FmuVariable* v = &MODEL_VARIABLES[vr];
        if (v->type == T_BINARY) {
            FmuBinary* bin = field(d, v, 0);
            free(bin->data);
            bin->data = NULL;
            bin->size = 0;
        } else if (v->type == T_STRING) {
            char** text = field(d, v, 0);
            free(*text);
            *text = NULL;
        }
    }
}

FmuSnapshot* fmu_snapshot_new(FmuInstance* inst, const char* fn) {
    FmuSnapshot* snap = calloc(1, sizeof *snap);
    if (snap == NULL || fmu_snapshot_update(inst, fn, snap) != FMU_OK) {
        free(snap);
        fmu_log_error(inst, "%s: out of memory while saving the FMU state", fn);
        return NULL;
    }
    return snap;
}

FmuStatus fmu_snapshot_update(FmuInstance* inst, const char* fn, FmuSnapshot* snap) {
    fmu_free_owned(&snap->d);
    *snap = inst->s;
    if (!copy_owned(&snap->d, &inst->s.d)) {
        fmu_log_error(inst, "%s: out of memory while saving the FMU state", fn);
        return FMU_FATAL;
    }
    return FMU_OK;
}

FmuStatus fmu_snapshot_restore(FmuInstance* inst, const char* fn, const FmuSnapshot* snap) {
    if (snap == NULL) {
        fmu_log_error(inst, "%s: the FMU state is NULL; pass a state returned by the get function", fn);
        return FMU_ERROR;
    }
    if (MODEL_STATE_AFTER_INIT && inst->s.mode == MODE_INSTANTIATED) {
        fmu_log_error(inst, "%s: this model takes a state only once initialised", fn);
        return FMU_ERROR;
    }
    fmu_free_owned(&inst->s.d);
    inst->s = *snap;
    inst->dirty = true;
    if (!copy_owned(&inst->s.d, &snap->d)) {
        fmu_log_error(inst, "%s: out of memory while restoring the FMU state", fn);
        return FMU_FATAL;
    }
    return FMU_OK;
}

void fmu_snapshot_free(FmuSnapshot* snap) {
    if (snap == NULL) return;
    fmu_free_owned(&snap->d);
    free(snap);
}
