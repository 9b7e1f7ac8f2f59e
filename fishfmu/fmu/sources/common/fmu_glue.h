/* Shared FMI 2.0 co-simulation glue of the fishfmu FMUs.
 *
 * fmu_glue.c implements every fmi2 function once; a model (model.c) only provides the four
 * functions declared at the end of this file.  All variables of a model, whatever their type,
 * live in one array `values[]` indexed by value reference: the value references are the
 * positions in the variable table that fishfmu/fmu_build.py generates (model_variables.h/.c)
 * from the model's variables.toml, the same table that writes modelDescription.xml, so the C
 * code and the XML cannot drift apart.  Integers and Booleans are stored as exact doubles.
 */
#ifndef FISHFMU_FMU_GLUE_H
#define FISHFMU_FMU_GLUE_H

#include <stddef.h>

#include "fmi2Functions.h"
#include "model_variables.h"

typedef enum { TYPE_REAL, TYPE_INTEGER, TYPE_BOOLEAN } VariableType;

typedef enum {
    CAUSALITY_PARAMETER,
    CAUSALITY_CALCULATED_PARAMETER,
    CAUSALITY_INPUT,
    CAUSALITY_OUTPUT,
    CAUSALITY_LOCAL
} Causality;

typedef enum { VARIABILITY_FIXED, VARIABILITY_TUNABLE, VARIABILITY_DISCRETE, VARIABILITY_CONTINUOUS } Variability;

/* One row of the generated variable table (min/max are +-HUGE_VAL when the XML gives none). */
typedef struct {
    const char *name;
    VariableType type;
    Causality causality;
    Variability variability;
    double start;
    double min;
    double max;
} VariableInfo;

extern const VariableInfo MODEL_VARIABLES[N_VARIABLES];

typedef enum {
    STATE_INSTANTIATED,
    STATE_INITIALIZATION_MODE,
    STATE_STEP_MODE,
    STATE_TERMINATED,
    STATE_ERROR
} InstanceState;

typedef struct ModelInstance {
    char *instance_name;
    fmi2CallbackLogger logger;
    fmi2CallbackAllocateMemory allocate_memory;
    fmi2CallbackFreeMemory free_memory;
    fmi2ComponentEnvironment environment;
    int logging_on;
    InstanceState state;
    double time_s;
    int parameters_dirty; /* a parameter was set since model_derive last ran */
    double values[N_VARIABLES];
    void *model; /* the model's own state, model_state_size() bytes, zeroed at reset */
} ModelInstance;

/* Rounding helpers for 0 <= x < 2^62, so that the binary needs no libm (a rebuild with any tool
 * links without -lm); isfinite() is a macro and needs no library either. */
static inline double fmu_abs(double x) { return x < 0.0 ? -x : x; }
static inline long fmu_ceil(double x) {
    long n = (long)x;
    return (double)n < x ? n + 1 : n;
}
static inline long fmu_floor(double x) {
    long n = (long)x;
    return (double)n > x ? n - 1 : n;
}

/* Log through the importer's logger; errors and warnings always, the rest only when logging is on. */
void fmu_log(const ModelInstance *inst, fmi2Status status, const char *fmt, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 3, 4)))
#endif
    ;

/* ---- provided by each model.c ---- */

/* Size of the model's own state struct. */
size_t model_state_size(void);

/* Check the parameters together (ranges are already checked one by one) and compute derived
 * values and calculated parameters.  Runs before the first step and after any parameter change. */
fmi2Status model_derive(ModelInstance *inst);

/* Set the initial state from the parameters and compute the outputs at the start time. */
void model_start(ModelInstance *inst);

/* Advance the model from inst->time_s by dt_s > 0 and update the outputs. */
fmi2Status model_do_step(ModelInstance *inst, double dt_s);

#endif
