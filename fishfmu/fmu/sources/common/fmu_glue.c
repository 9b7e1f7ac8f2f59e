/* FMI 2.0 co-simulation interface shared by the fishfmu FMUs (see fmu_glue.h).
 *
 * What this file guarantees for every model:
 * - the GUID passed to fmi2Instantiate matches the one compiled in, and only co-simulation is offered;
 * - every value set is checked before it is stored: the variable exists and has the right type,
 *   its causality/variability allows setting it in the current state, a Real is finite, and the
 *   value lies within the min/max of the modelDescription.  A rejected value returns fmi2Error
 *   with a log message and leaves the stored value unchanged;
 * - the parameters are checked together (model_derive) before the first step and before the
 *   next step after a tunable parameter changed;
 * - doStep refuses a communication point that does not match the FMU's time (no rollback).
 * Model exchange functions exist only so that importers that look up every symbol can load
 * the library; they return fmi2Error.
 */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmu_glue.h"

#define UNUSED(x) (void)(x)

static const char *STATUS_CATEGORY[] = {"logEvents", "logStatusWarning", "logStatusDiscard", "logStatusError",
                                        "logStatusFatal", "logStatusPending"};

void fmu_log(const ModelInstance *inst, fmi2Status status, const char *fmt, ...) {
    char text[600];
    char escaped[1200];
    va_list args;
    size_t i, j = 0;
    if (inst == NULL || inst->logger == NULL) return;
    if (status == fmi2OK && !inst->logging_on) return;
    va_start(args, fmt);
    vsnprintf(text, sizeof(text), fmt, args);
    va_end(args);
    /* the importer treats the message as a printf format: keep our text literal */
    for (i = 0; text[i] != '\0' && j + 2 < sizeof(escaped); i++) {
        if (text[i] == '%') escaped[j++] = '%';
        escaped[j++] = text[i];
    }
    escaped[j] = '\0';
    inst->logger(inst->environment, inst->instance_name, status, STATUS_CATEGORY[status], escaped);
}

static const char *STATE_NAME[] = {"instantiated", "initialization mode", "step mode", "terminated", "error"};

static fmi2Status not_allowed(ModelInstance *inst, const char *function) {
    fmu_log(inst, fmi2Error, "%s is not allowed in state '%s'", function, STATE_NAME[inst->state]);
    return fmi2Error;
}

static void set_start_values(ModelInstance *inst) {
    size_t k;
    for (k = 0; k < N_VARIABLES; k++) inst->values[k] = MODEL_VARIABLES[k].start;
    memset(inst->model, 0, model_state_size());
    inst->parameters_dirty = 1;
}

/* Recompute derived values and the start outputs while the importer is still setting values. */
static fmi2Status refresh_before_step_mode(ModelInstance *inst) {
    fmi2Status status;
    if (!inst->parameters_dirty) return fmi2OK;
    status = model_derive(inst);
    if (status > fmi2Warning) return status;
    model_start(inst);
    inst->parameters_dirty = 0;
    return status;
}

/* ---------------------------------------------------------------- common functions */

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    ModelInstance *inst = (ModelInstance *)c;
    size_t i, k;
    if (inst == NULL) return fmi2Error;
    for (i = 0; i < nCategories; i++) {
        int known = 0;
        for (k = 0; k < sizeof(STATUS_CATEGORY) / sizeof(STATUS_CATEGORY[0]); k++)
            if (categories[i] != NULL && strcmp(categories[i], STATUS_CATEGORY[k]) == 0) known = 1;
        if (!known) {
            fmu_log(inst, fmi2Error, "unknown log category '%s'", categories[i] ? categories[i] : "(null)");
            return fmi2Error;
        }
    }
    inst->logging_on = loggingOn ? 1 : 0;
    return fmi2OK;
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn) {
    ModelInstance *inst;
    ModelInstance reporter; /* only to report problems found before allocating */
    fmi2CallbackAllocateMemory allocate = (functions && functions->allocateMemory) ? functions->allocateMemory : calloc;
    UNUSED(fmuResourceLocation);
    UNUSED(visible);

    memset(&reporter, 0, sizeof(reporter));
    reporter.logger = functions ? functions->logger : NULL;
    reporter.environment = functions ? functions->componentEnvironment : NULL;
    reporter.instance_name = (char *)(instanceName ? instanceName : MODEL_IDENTIFIER);
    if (instanceName == NULL || instanceName[0] == '\0') {
        fmu_log(&reporter, fmi2Error, "fmi2Instantiate: missing instance name");
        return NULL;
    }
    if (fmuType != fmi2CoSimulation) {
        fmu_log(&reporter, fmi2Error, "fmi2Instantiate: %s supports co-simulation only", MODEL_IDENTIFIER);
        return NULL;
    }
    if (fmuGUID == NULL || strcmp(fmuGUID, MODEL_GUID) != 0) {
        fmu_log(&reporter, fmi2Error, "fmi2Instantiate: GUID '%s' does not match the binary's %s",
                fmuGUID ? fmuGUID : "(null)", MODEL_GUID);
        return NULL;
    }

    inst = (ModelInstance *)allocate(1, sizeof(ModelInstance));
    if (inst == NULL) return NULL;
    inst->allocate_memory = allocate;
    inst->free_memory = (functions && functions->freeMemory) ? functions->freeMemory : free;
    inst->logger = reporter.logger;
    inst->environment = reporter.environment;
    inst->logging_on = loggingOn ? 1 : 0;
    inst->instance_name = (char *)allocate(strlen(instanceName) + 1, 1);
    inst->model = allocate(1, model_state_size());
    if (inst->instance_name == NULL || inst->model == NULL) {
        if (inst->instance_name) inst->free_memory(inst->instance_name);
        if (inst->model) inst->free_memory(inst->model);
        inst->free_memory(inst);
        return NULL;
    }
    strcpy(inst->instance_name, instanceName);
    inst->state = STATE_INSTANTIATED;
    inst->time_s = 0.0;
    set_start_values(inst);
    return inst;
}

void fmi2FreeInstance(fmi2Component c) {
    ModelInstance *inst = (ModelInstance *)c;
    if (inst == NULL) return;
    inst->free_memory(inst->model);
    inst->free_memory(inst->instance_name);
    inst->free_memory(inst);
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    ModelInstance *inst = (ModelInstance *)c;
    UNUSED(toleranceDefined);
    UNUSED(tolerance);
    if (inst == NULL) return fmi2Error;
    if (inst->state != STATE_INSTANTIATED) return not_allowed(inst, "fmi2SetupExperiment");
    if (!isfinite(startTime) || (stopTimeDefined && !(stopTime >= startTime))) {
        fmu_log(inst, fmi2Error, "fmi2SetupExperiment: bad start time %g or stop time %g", startTime, stopTime);
        return fmi2Error;
    }
    inst->time_s = startTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    ModelInstance *inst = (ModelInstance *)c;
    if (inst == NULL) return fmi2Error;
    if (inst->state != STATE_INSTANTIATED) return not_allowed(inst, "fmi2EnterInitializationMode");
    inst->state = STATE_INITIALIZATION_MODE;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    ModelInstance *inst = (ModelInstance *)c;
    fmi2Status status;
    if (inst == NULL) return fmi2Error;
    if (inst->state != STATE_INITIALIZATION_MODE) return not_allowed(inst, "fmi2ExitInitializationMode");
    inst->parameters_dirty = 1; /* always start from the values as they are now */
    status = refresh_before_step_mode(inst);
    if (status > fmi2Warning) {
        inst->state = STATE_ERROR;
        return status;
    }
    inst->state = STATE_STEP_MODE;
    return status;
}

fmi2Status fmi2Terminate(fmi2Component c) {
    ModelInstance *inst = (ModelInstance *)c;
    if (inst == NULL) return fmi2Error;
    if (inst->state != STATE_STEP_MODE && inst->state != STATE_ERROR) return not_allowed(inst, "fmi2Terminate");
    inst->state = STATE_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component c) {
    ModelInstance *inst = (ModelInstance *)c;
    if (inst == NULL) return fmi2Error;
    inst->state = STATE_INSTANTIATED;
    inst->time_s = 0.0;
    set_start_values(inst);
    return fmi2OK;
}

/* ---------------------------------------------------------------- getting and setting values */

static fmi2Status check_reference(ModelInstance *inst, const char *function, fmi2ValueReference vr,
                                  VariableType type) {
    static const char *TYPE_NAME[] = {"Real", "Integer", "Boolean"};
    if (vr >= N_VARIABLES) {
        fmu_log(inst, fmi2Error, "%s: unknown value reference %u", function, (unsigned)vr);
        return fmi2Error;
    }
    if (MODEL_VARIABLES[vr].type != type) {
        fmu_log(inst, fmi2Error, "%s: '%s' (value reference %u) is a %s, not a %s", function,
                MODEL_VARIABLES[vr].name, (unsigned)vr, TYPE_NAME[MODEL_VARIABLES[vr].type], TYPE_NAME[type]);
        return fmi2Error;
    }
    return fmi2OK;
}

static fmi2Status get_values(ModelInstance *inst, const char *function, const fmi2ValueReference vr[], size_t nvr,
                             VariableType type, double out[]) {
    size_t k;
    fmi2Status status = fmi2OK;
    if (inst == NULL) return fmi2Error;
    if (nvr > 0 && (vr == NULL || out == NULL)) return fmi2Error;
    if (inst->state == STATE_TERMINATED || inst->state == STATE_ERROR) {
        /* values stay readable after terminate/error for post-mortem inspection */
    } else if (inst->state != STATE_STEP_MODE) {
        status = refresh_before_step_mode(inst);
        if (status > fmi2Warning) return status;
    }
    for (k = 0; k < nvr; k++) {
        if (check_reference(inst, function, vr[k], type) != fmi2OK) return fmi2Error;
        out[k] = inst->values[vr[k]];
    }
    return status;
}

/* May this variable be set now?  (FMI 2.0 section 4.2.4, co-simulation, simplified.) */
static int settable(const ModelInstance *inst, const VariableInfo *var) {
    int before_step_mode = inst->state == STATE_INSTANTIATED || inst->state == STATE_INITIALIZATION_MODE;
    switch (var->causality) {
    case CAUSALITY_PARAMETER:
        return before_step_mode || (inst->state == STATE_STEP_MODE && var->variability == VARIABILITY_TUNABLE);
    case CAUSALITY_INPUT:
        return before_step_mode || inst->state == STATE_STEP_MODE;
    default:
        return 0;
    }
}

static fmi2Status set_values(ModelInstance *inst, const char *function, const fmi2ValueReference vr[], size_t nvr,
                             VariableType type, const double in[]) {
    size_t k;
    if (inst == NULL) return fmi2Error;
    if (nvr > 0 && (vr == NULL || in == NULL)) return fmi2Error;
    for (k = 0; k < nvr; k++) {
        const VariableInfo *var;
        if (check_reference(inst, function, vr[k], type) != fmi2OK) return fmi2Error;
        var = &MODEL_VARIABLES[vr[k]];
        if (!settable(inst, var)) {
            fmu_log(inst, fmi2Error, "%s: '%s' cannot be set in state '%s'", function, var->name,
                    STATE_NAME[inst->state]);
            return fmi2Error;
        }
        if (!isfinite(in[k])) {
            fmu_log(inst, fmi2Error, "%s: '%s' = %g is not a finite number", function, var->name, in[k]);
            return fmi2Error;
        }
        if (in[k] < var->min || in[k] > var->max) {
            fmu_log(inst, fmi2Error, "%s: '%s' = %g is outside its range [%g, %g]", function, var->name, in[k],
                    var->min, var->max);
            return fmi2Error;
        }
        inst->values[vr[k]] = in[k];
        if (var->causality == CAUSALITY_PARAMETER || inst->state != STATE_STEP_MODE) inst->parameters_dirty = 1;
    }
    return fmi2OK;
}

#define MAX_BATCH 256 /* values converted per call chunk; larger requests are processed in chunks */

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[]) {
    return get_values((ModelInstance *)c, "fmi2GetReal", vr, nvr, TYPE_REAL, value);
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[]) {
    return set_values((ModelInstance *)c, "fmi2SetReal", vr, nvr, TYPE_REAL, value);
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[]) {
    double buffer[MAX_BATCH];
    size_t done, k, n;
    fmi2Status status = fmi2OK, s;
    for (done = 0; done < nvr; done += n) {
        n = nvr - done < MAX_BATCH ? nvr - done : MAX_BATCH;
        s = get_values((ModelInstance *)c, "fmi2GetInteger", vr + done, n, TYPE_INTEGER, buffer);
        if (s > fmi2Warning) return s;
        if (s > status) status = s;
        for (k = 0; k < n; k++) value[done + k] = (fmi2Integer)buffer[k];
    }
    return status;
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Integer value[]) {
    double buffer[MAX_BATCH];
    size_t done, k, n;
    fmi2Status s;
    for (done = 0; done < nvr; done += n) {
        n = nvr - done < MAX_BATCH ? nvr - done : MAX_BATCH;
        for (k = 0; k < n; k++) buffer[k] = (double)value[done + k];
        s = set_values((ModelInstance *)c, "fmi2SetInteger", vr + done, n, TYPE_INTEGER, buffer);
        if (s != fmi2OK) return s;
    }
    return fmi2OK;
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Boolean value[]) {
    double buffer[MAX_BATCH];
    size_t done, k, n;
    fmi2Status status = fmi2OK, s;
    for (done = 0; done < nvr; done += n) {
        n = nvr - done < MAX_BATCH ? nvr - done : MAX_BATCH;
        s = get_values((ModelInstance *)c, "fmi2GetBoolean", vr + done, n, TYPE_BOOLEAN, buffer);
        if (s > fmi2Warning) return s;
        if (s > status) status = s;
        for (k = 0; k < n; k++) value[done + k] = buffer[k] != 0.0 ? fmi2True : fmi2False;
    }
    return status;
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Boolean value[]) {
    double buffer[MAX_BATCH];
    size_t done, k, n;
    fmi2Status s;
    for (done = 0; done < nvr; done += n) {
        n = nvr - done < MAX_BATCH ? nvr - done : MAX_BATCH;
        for (k = 0; k < n; k++) buffer[k] = value[done + k] ? 1.0 : 0.0;
        s = set_values((ModelInstance *)c, "fmi2SetBoolean", vr + done, n, TYPE_BOOLEAN, buffer);
        if (s != fmi2OK) return s;
    }
    return fmi2OK;
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2String value[]) {
    UNUSED(value);
    if (nvr == 0) return fmi2OK;
    fmu_log((ModelInstance *)c, fmi2Error, "fmi2GetString: this FMU has no String variables (value reference %u)",
            (unsigned)vr[0]);
    return fmi2Error;
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2String value[]) {
    UNUSED(value);
    if (nvr == 0) return fmi2OK;
    fmu_log((ModelInstance *)c, fmi2Error, "fmi2SetString: this FMU has no String variables (value reference %u)",
            (unsigned)vr[0]);
    return fmi2Error;
}

/* ---------------------------------------------------------------- unsupported optional features */

static fmi2Status unsupported(fmi2Component c, const char *function) {
    fmu_log((ModelInstance *)c, fmi2Error, "%s is not supported by %s", function, MODEL_IDENTIFIER);
    return fmi2Error;
}

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *s) {
    UNUSED(s);
    return unsupported(c, "fmi2GetFMUstate");
}
fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate s) {
    UNUSED(s);
    return unsupported(c, "fmi2SetFMUstate");
}
fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *s) {
    UNUSED(s);
    return unsupported(c, "fmi2FreeFMUstate");
}
fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate s, size_t *size) {
    UNUSED(s);
    UNUSED(size);
    return unsupported(c, "fmi2SerializedFMUstateSize");
}
fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate s, fmi2Byte b[], size_t size) {
    UNUSED(s);
    UNUSED(b);
    UNUSED(size);
    return unsupported(c, "fmi2SerializeFMUstate");
}
fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte b[], size_t size, fmi2FMUstate *s) {
    UNUSED(b);
    UNUSED(size);
    UNUSED(s);
    return unsupported(c, "fmi2DeSerializeFMUstate");
}
fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vu[], size_t nu,
                                        const fmi2ValueReference vk[], size_t nk, const fmi2Real dvk[],
                                        fmi2Real dvu[]) {
    UNUSED(vu);
    UNUSED(nu);
    UNUSED(vk);
    UNUSED(nk);
    UNUSED(dvk);
    UNUSED(dvu);
    return unsupported(c, "fmi2GetDirectionalDerivative");
}

/* model exchange: not offered (the modelDescription has no <ModelExchange>) */
fmi2Status fmi2EnterEventMode(fmi2Component c) { return unsupported(c, "fmi2EnterEventMode"); }
fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *e) {
    UNUSED(e);
    return unsupported(c, "fmi2NewDiscreteStates");
}
fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) { return unsupported(c, "fmi2EnterContinuousTimeMode"); }
fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean noSet, fmi2Boolean *enter, fmi2Boolean *term) {
    UNUSED(noSet);
    UNUSED(enter);
    UNUSED(term);
    return unsupported(c, "fmi2CompletedIntegratorStep");
}
fmi2Status fmi2SetTime(fmi2Component c, fmi2Real t) {
    UNUSED(t);
    return unsupported(c, "fmi2SetTime");
}
fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t nx) {
    UNUSED(x);
    UNUSED(nx);
    return unsupported(c, "fmi2SetContinuousStates");
}
fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real dx[], size_t nx) {
    UNUSED(dx);
    UNUSED(nx);
    return unsupported(c, "fmi2GetDerivatives");
}
fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real z[], size_t nz) {
    UNUSED(z);
    UNUSED(nz);
    return unsupported(c, "fmi2GetEventIndicators");
}
fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t nx) {
    UNUSED(x);
    UNUSED(nx);
    return unsupported(c, "fmi2GetContinuousStates");
}
fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x[], size_t nx) {
    UNUSED(x);
    UNUSED(nx);
    return unsupported(c, "fmi2GetNominalsOfContinuousStates");
}

/* ---------------------------------------------------------------- co-simulation */

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    UNUSED(vr);
    UNUSED(nvr);
    UNUSED(order);
    UNUSED(value);
    return unsupported(c, "fmi2SetRealInputDerivatives");
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[]) {
    UNUSED(vr);
    UNUSED(nvr);
    UNUSED(order);
    UNUSED(value);
    return unsupported(c, "fmi2GetRealOutputDerivatives");
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    ModelInstance *inst = (ModelInstance *)c;
    fmi2Status status = fmi2OK, s;
    double t = currentCommunicationPoint, dt = communicationStepSize;
    UNUSED(noSetFMUStatePriorToCurrentPoint);
    if (inst == NULL) return fmi2Error;
    if (inst->state != STATE_STEP_MODE) return not_allowed(inst, "fmi2DoStep");
    if (!isfinite(dt) || dt <= 0.0) {
        fmu_log(inst, fmi2Error, "fmi2DoStep: communication step %g s must be positive", dt);
        return fmi2Error;
    }
    /* the master's clock rules, but a jump means it skipped or repeated a step */
    if (!isfinite(t) || fmu_abs(t - inst->time_s) > 1e-6 + 1e-9 * fmu_abs(t)) {
        fmu_log(inst, fmi2Error, "fmi2DoStep: communication point %.9g s is not the FMU's time %.9g s", t,
                inst->time_s);
        return fmi2Error;
    }
    inst->time_s = t;
    if (inst->parameters_dirty) {
        status = model_derive(inst);
        if (status > fmi2Warning) return status; /* the rejected tunable value can be set again */
        inst->parameters_dirty = 0;
    }
    s = model_do_step(inst, dt);
    if (s > fmi2Warning) {
        inst->state = STATE_ERROR;
        return s;
    }
    inst->time_s = t + dt;
    return s > status ? s : status;
}

fmi2Status fmi2CancelStep(fmi2Component c) { return unsupported(c, "fmi2CancelStep"); }

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    UNUSED(s);
    UNUSED(value);
    return unsupported(c, "fmi2GetStatus");
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    ModelInstance *inst = (ModelInstance *)c;
    if (inst == NULL || value == NULL) return fmi2Error;
    if (s != fmi2LastSuccessfulTime) return unsupported(c, "fmi2GetRealStatus for this status kind");
    *value = inst->time_s;
    return fmi2OK;
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value) {
    UNUSED(s);
    UNUSED(value);
    return unsupported(c, "fmi2GetIntegerStatus");
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value) {
    if (c == NULL || value == NULL) return fmi2Error;
    if (s != fmi2Terminated) return unsupported(c, "fmi2GetBooleanStatus for this status kind");
    *value = fmi2False;
    return fmi2OK;
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
    UNUSED(s);
    UNUSED(value);
    return unsupported(c, "fmi2GetStringStatus");
}
