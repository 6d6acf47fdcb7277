/* Version-independent core of the fmu-bridge example models.
 *
 * The FMI wrappers (fmi1_cs.c, fmi2.c, fmi3.c) own the FMI calling conventions; this core owns the
 * instance data, the generated variable table (model_gen.h/.c, written by bridge/models.py from
 * models/<name>/model.json), the mode checks, logging, FMU state snapshots and the RK4 helper.
 * Each model implements the four functions declared at the end of this file in models/<name>/model.c. */
#ifndef FMU_CORE_H
#define FMU_CORE_H

#include "fmu_types.h"
#include "model_gen.h"

typedef enum {
    MODE_INSTANTIATED, MODE_INITIALIZATION, MODE_STEP, MODE_EVENT, MODE_CONTINUOUS,
    MODE_TERMINATED, MODE_ERROR
} FmuMode;

#define FMU_MODE_BIT(m) (1u << (m))

typedef enum { LOG_EVENTS = 0, LOG_STATUS_WARNING = 1, LOG_STATUS_ERROR = 2, LOG_N_CATEGORIES = 3 } FmuLogCategory;

extern const char* const FMU_LOG_CATEGORY_NAMES[LOG_N_CATEGORIES];

/* Everything an FMU state snapshot (fmi2GetFMUstate / fmi3GetFMUState) copies. */
typedef struct {
    double time;
    FmuMode mode;
    bool terminate_requested;   /* the model asked the importer to stop the simulation */
    ModelData d;
} FmuSnapshot;

typedef struct FmuInstance FmuInstance;

/* Passes one formatted message to the FMI logger of the wrapper's version. */
typedef void (*FmuEmit)(FmuInstance* inst, FmuStatus status, const char* category, const char* message);

/* The wrappers embed this struct as the first member of their own instance struct. */
struct FmuInstance {
    char* name;
    int fmi_version;            /* 1, 2 or 3 */
    FmuInterface interface;
    FmuEmit emit;               /* NULL: the importer gave no logger */
    bool logging_on;
    bool categories[LOG_N_CATEGORIES];
    bool dirty;                 /* inputs or states changed since the last model_evaluate */
    FmuSnapshot s;
};

/* --- life cycle ---------------------------------------------------------------------------- */
FmuStatus fmu_setup(FmuInstance* inst, const char* fn, const char* name, const char* token,
                    FmuInterface requested, bool logging_on);
void fmu_teardown(FmuInstance* inst);
FmuStatus fmu_reset(FmuInstance* inst, const char* fn);
FmuStatus fmu_enter_initialization(FmuInstance* inst, const char* fn, double start_time);
FmuStatus fmu_exit_initialization(FmuInstance* inst, const char* fn);
FmuStatus fmu_terminate(FmuInstance* inst, const char* fn);
FmuStatus fmu_set_debug_logging(FmuInstance* inst, const char* fn, bool on, size_t n, const char* const names[]);

/* --- checks and logging -------------------------------------------------------------------- */
bool fmu_check_mode(FmuInstance* inst, unsigned allowed, const char* fn);
bool fmu_check_interface(FmuInstance* inst, FmuInterface required, const char* fn);
FmuStatus fmu_unsupported(FmuInstance* inst, const char* fn, const char* what);
void fmu_log(FmuInstance* inst, FmuStatus status, FmuLogCategory category, const char* fmt, ...)
    __attribute__((format(printf, 4, 5)));
#define fmu_log_error(inst, ...) fmu_log((inst), FMU_ERROR, LOG_STATUS_ERROR, __VA_ARGS__)
#define fmu_log_warning(inst, ...) fmu_log((inst), FMU_WARNING, LOG_STATUS_WARNING, __VA_ARGS__)
#define fmu_log_event(inst, ...) fmu_log((inst), FMU_OK, LOG_EVENTS, __VA_ARGS__)

/* --- variables ----------------------------------------------------------------------------- */
FmuStatus fmu_get(FmuInstance* inst, const char* fn, unsigned type_mask, unsigned vr, FmuValue* out);
FmuStatus fmu_set(FmuInstance* inst, const char* fn, unsigned type_mask, unsigned vr, const FmuValue* in);
/* FMI 3.0 arrays: element index (row-major) of the variable vr; scalars have the one element 0. */
FmuStatus fmu_get_element(FmuInstance* inst, const char* fn, unsigned type_mask, unsigned vr, size_t index,
                          FmuValue* out);
FmuStatus fmu_set_element(FmuInstance* inst, const char* fn, unsigned type_mask, unsigned vr, size_t index,
                          const FmuValue* in);
/* Number of values of vr in an FMI 3.0 get/set call: its element count, 1 for scalars and unknown vrs. */
size_t fmu_value_count(unsigned vr);
/* Replace dst's bytes with an instance-owned copy of size bytes at data; false when out of memory. */
bool fmu_binary_assign(FmuBinary* dst, const uint8_t* data, size_t size);
bool fmu_check_count(FmuInstance* inst, const char* fn, size_t given, size_t expected, const char* what);

/* --- snapshots (FMU state) ----------------------------------------------------------------- */
FmuSnapshot* fmu_snapshot_new(FmuInstance* inst, const char* fn);
FmuStatus fmu_snapshot_update(FmuInstance* inst, const char* fn, FmuSnapshot* snap);
FmuStatus fmu_snapshot_restore(FmuInstance* inst, const char* fn, const FmuSnapshot* snap);
void fmu_snapshot_free(FmuSnapshot* snap);
void fmu_free_owned(ModelData* d); /* strings and binaries */
/* Serialised snapshots (fmu_serial.c), for models built with MODEL_CAN_SERIALIZE; else FMU_ERROR. */
FmuStatus fmu_serialized_size(FmuInstance* inst, const char* fn, const FmuSnapshot* snap, size_t* size);
FmuStatus fmu_serialize(FmuInstance* inst, const char* fn, const FmuSnapshot* snap, uint8_t* out, size_t size);
FmuStatus fmu_deserialize(FmuInstance* inst, const char* fn, const uint8_t* in, size_t size, FmuSnapshot** snap);

/* --- co-simulation ------------------------------------------------------------------------- */
FmuStatus fmu_do_step(FmuInstance* inst, const char* fn, double t, double h);
/* Classic RK4 on the continuous states over [s.time, s.time + h] in equal substeps of at most
 * max_substep seconds; inputs are held constant (zero-order hold). */
void fmu_rk4(FmuInstance* inst, double h, double max_substep);

/* --- model exchange ------------------------------------------------------------------------ */
FmuStatus fmu_set_time(FmuInstance* inst, const char* fn, double time);
FmuStatus fmu_enter_event_mode(FmuInstance* inst, const char* fn);
FmuStatus fmu_enter_continuous_mode(FmuInstance* inst, const char* fn);
FmuStatus fmu_event_update(FmuInstance* inst, const char* fn, FmuEventResult* ev);
FmuStatus fmu_get_states(FmuInstance* inst, const char* fn, double x[], size_t nx);
FmuStatus fmu_set_states(FmuInstance* inst, const char* fn, const double x[], size_t nx);
FmuStatus fmu_get_derivatives(FmuInstance* inst, const char* fn, double dx[], size_t nx);
FmuStatus fmu_get_nominals(FmuInstance* inst, const char* fn, double nominals[], size_t nx);
FmuStatus fmu_get_event_indicators(FmuInstance* inst, const char* fn, double z[], size_t nz);

/* --- implemented by each model (models/<name>/model.c) ------------------------------------- */
/* At the exit of initialization mode: check parameters, set the states from their start-value
 * parameters, compute calculated parameters. Log and return FMU_ERROR to reject. */
FmuStatus model_initialize(FmuInstance* inst);
/* Compute derivatives, event indicators and algebraic outputs from time, states, inputs and
 * parameters. Must not change states or discrete variables (it is called lazily before reads). */
void model_evaluate(FmuInstance* inst);
/* Model exchange, event mode: handle the events at the current time. */
void model_event_update(FmuInstance* inst, FmuEventResult* ev);
/* Co-simulation: advance from s.time by h seconds (0 < h <= MODEL_MAX_STEP, checked by the core).
 * Set s.terminate_requested to ask the importer to stop; the core sets s.time = t + h after. */
FmuStatus model_do_step(FmuInstance* inst, double h);

#endif /* FMU_CORE_H */
