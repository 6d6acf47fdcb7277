/* Serialised FMU states (fmi2SerializeFMUstate / fmi3SerializeFMUState) for models whose model.json
 * sets "can_serialize": the snapshot holds no pointers there (no String or Binary variables), so its
 * bytes are the state. The bytes carry a magic number and the snapshot's size, and the deserialiser
 * checks both and the mode, so that bytes of another model or of another build are refused. */
#include "fmu_core.h"

#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#define SERIAL_MAGIC UINT32_C(0x31534246) /* "FBS1" */

typedef struct {
    uint32_t magic;
    uint32_t snapshot_size;
} SerialHeader;

static const size_t SERIAL_SIZE = sizeof(SerialHeader) + sizeof(FmuSnapshot);

static bool serializable(FmuInstance* inst, const char* fn) {
    if (MODEL_CAN_SERIALIZE) return true;
    fmu_unsupported(inst, fn, inst->fmi_version == 2 ? "canSerializeFMUstate is false" : "canSerializeFMUState is false");
    return false;
}

FmuStatus fmu_serialized_size(FmuInstance* inst, const char* fn, const FmuSnapshot* snap, size_t* size) {
    if (!serializable(inst, fn)) return FMU_ERROR;
    if (snap == NULL) {
        fmu_log_error(inst, "%s: the FMU state is NULL; pass a state returned by the get function", fn);
        return FMU_ERROR;
    }
    *size = SERIAL_SIZE;
    return FMU_OK;
}

FmuStatus fmu_serialize(FmuInstance* inst, const char* fn, const FmuSnapshot* snap, uint8_t* out, size_t size) {
    if (!serializable(inst, fn)) return FMU_ERROR;
    if (snap == NULL || out == NULL || size != SERIAL_SIZE) {
        fmu_log_error(inst, "%s: need a state and a buffer of %zu bytes, got %zu bytes", fn, SERIAL_SIZE, size);
        return FMU_ERROR;
    }
    const SerialHeader header = {SERIAL_MAGIC, (uint32_t)sizeof(FmuSnapshot)};
    memcpy(out, &header, sizeof header);
    memcpy(out + sizeof header, snap, sizeof *snap);
    return FMU_OK;
}

FmuStatus fmu_deserialize(FmuInstance* inst, const char* fn, const uint8_t* in, size_t size, FmuSnapshot** snap) {
    if (!serializable(inst, fn)) return FMU_ERROR;
    if (MODEL_STATE_AFTER_INIT && inst->s.mode == MODE_INSTANTIATED) {
        fmu_log_error(inst, "%s: this model reads a state only once initialised", fn);
        return FMU_ERROR;
    }
    SerialHeader header = {0, 0};
    if (in != NULL && size >= sizeof header) memcpy(&header, in, sizeof header);
    if (in == NULL || size != SERIAL_SIZE || header.magic != SERIAL_MAGIC ||
        header.snapshot_size != sizeof(FmuSnapshot)) {
        fmu_log_error(inst, "%s: these %zu bytes are not a serialised state of %s (expected %zu bytes)", fn, size,
                      MODEL_NAME, SERIAL_SIZE);
        return FMU_ERROR;
    }
    FmuSnapshot* copy = calloc(1, sizeof *copy);
    if (copy == NULL) {
        fmu_log_error(inst, "%s: out of memory while reading the FMU state", fn);
        return FMU_FATAL;
    }
    memcpy(copy, in + sizeof header, sizeof *copy);
    if (copy->mode < MODE_INSTANTIATED || copy->mode > MODE_TERMINATED || copy->mode == MODE_INITIALIZATION) {
        fmu_log_error(inst, "%s: the serialised state has an invalid mode (%d)", fn, (int)copy->mode);
        free(copy);
        return FMU_ERROR;
    }
    *snap = copy;
    return FMU_OK;
}
