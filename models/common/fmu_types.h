/* Types shared by the fmu-bridge example models, the generated variable tables and the FMI wrappers.
 *
 * Nothing in here depends on an FMI version: the wrappers (fmi1_cs.c, fmi2.c, fmi3.c) translate
 * between these types and the FMI types of their version. */
#ifndef FMU_TYPES_H
#define FMU_TYPES_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

/* Same numeric order as fmi1Status, fmi2Status and fmi3Status. */
typedef enum { FMU_OK = 0, FMU_WARNING = 1, FMU_DISCARD = 2, FMU_ERROR = 3, FMU_FATAL = 4 } FmuStatus;

typedef enum { FMU_CS = 1, FMU_ME = 2 } FmuInterface;

/* T_NONE is 0 so that an unused (zero-initialised) row of the variable table is never a variable. */
typedef enum {
    T_NONE, T_FLOAT32, T_FLOAT64, T_INT8, T_UINT8, T_INT16, T_UINT16, T_INT32, T_UINT32,
    T_INT64, T_UINT64, T_BOOLEAN, T_STRING, T_ENUMERATION, T_BINARY, T_CLOCK
} FmuType;

/* FMI 3.0 Binary storage: instance-owned bytes; data is never NULL after setup (an empty value
 * points at one allocated byte), so an importer always receives a valid pointer. */
typedef struct {
    uint8_t* data;
    size_t size;
} FmuBinary;

/* Bit masks of accepted types, used by the typed get/set functions of the wrappers. */
#define FMU_TYPE_BIT(t) (1u << (t))

typedef enum {
    C_PARAMETER, C_CALCULATED_PARAMETER, C_INPUT, C_OUTPUT, C_LOCAL, C_INDEPENDENT
} FmuCausality;

typedef enum { V_CONSTANT, V_FIXED, V_TUNABLE, V_DISCRETE, V_CONTINUOUS } FmuVariability;

/* One row of the generated variable table (model_gen.c), indexed by value reference.
 * Storage: Float32 float, Float64 double, IntN/UIntN intN_t/uintN_t, Boolean bool,
 * Enumeration int64_t, String char* (owned by the instance, always non-NULL after setup),
 * Binary FmuBinary, Clock bool (active). An FMI 3.0 array (n_elements > 0) is a C array of its
 * element type in row-major order. */
typedef struct {
    const char* name;
    FmuType type;            /* T_NONE marks an unused value reference */
    FmuCausality causality;
    FmuVariability variability;
    bool exposed;            /* declared in this variant's modelDescription.xml */
    size_t offset;           /* offsetof(ModelData, field) */
    bool has_start;
    double start_real;       /* Float32, Float64 */
    int64_t start_int;       /* signed integers, Enumeration, Boolean (0/1) */
    uint64_t start_uint;     /* unsigned integers */
    const char* start_string;
    bool has_min;
    bool has_max;
    double min;              /* declarations only: values outside are accepted and logged */
    double max;
    size_t n_elements;       /* FMI 3.0 arrays: number of elements; 0 for a scalar */
    const double* start_array;   /* Float64 arrays: one start value per element */
    const uint8_t* start_binary; /* Binary: start bytes (start_size of them) */
    size_t start_size;
    double interval;         /* Clock: interval in s of a clock with a constant interval */
} FmuVariable;

/* A scalar in transit between a wrapper and the variable table. */
typedef union {
    double f;
    int64_t i;
    uint64_t u;
    bool b;
    const char* s;
    struct {
        const uint8_t* data;
        size_t size;
    } bin;
} FmuValue;

/* Result of a model-exchange event update (maps onto fmi2EventInfo / fmi3UpdateDiscreteStates). */
typedef struct {
    bool discrete_states_need_update;
    bool terminate_simulation;
    bool values_of_continuous_states_changed;
    bool next_event_time_defined;
    double next_event_time;
} FmuEventResult;

#endif /* FMU_TYPES_H */
