/* Two small FMI 3.0 co-simulation FMUs with events, for tests of the master's event mode (issue 44); the Modelica
 * Reference FMUs' Stair and BouncingBall could not be had from a package registry, so these stand in for them.
 *
 * MODEL_STAIR  (time events): Int32 output counter, 0 at the start, +1 at every t = k * period (k = 1, 2, ...).
 * MODEL_TASK   (a periodic input clock, a PLC task): Int32 output count, +1 at each tick of the input clock tick
 *              (every 0.025 s from t = 0, the master ticks it), Float64 output last_tick, the time of the last tick.
 * MODEL_BALL   (state events): a ball dropped from h0, Float64 outputs h and v; at h = 0 it bounces, v -> -e * v.
 *              Between bounces it moves on its exact parabola, so a bounce is found where the event indicator h
 *              crosses zero to rounding (t1 = sqrt(2 h0 / g), then each flight is 2 e^k v1 / g); below v_min it rests.
 *
 * With event mode (fmi3InstantiateCoSimulation with eventModeUsed and earlyReturnAllowed) doStep returns early at an
 * event (earlyReturn, lastSuccessfulTime = the event's time, eventHandlingNeeded) and the event is handled in
 * fmi3UpdateDiscreteStates; without it the FMU handles its events inside doStep, as an FMU without event mode does.
 * Only the functions a co-simulation master calls are exported. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "fmi3Functions.h"

typedef struct {
    fmi3Float64 time;
    fmi3Boolean event_mode, early_return, pending;
    fmi3Float64 period;       /* stair */
    fmi3Int32 counter;
    fmi3Float64 g, e, h0, v_min, h, v;  /* ball: the arc starts at (time of h, v) */
    fmi3Boolean resting;
    fmi3Boolean tick;         /* task: the clock is active (set by the master in event mode) */
    fmi3Float64 last_tick;
} Model;

enum { VR_TIME = 0, VR_A = 1, VR_B = 2, VR_C = 3, VR_D = 4, VR_E = 5, VR_F = 6 };

#if defined(MODEL_TASK)
static fmi3Float64 next_event(const Model *m) { (void)m; return INFINITY; }  /* its events are the clock's ticks */
static void advance(Model *m, fmi3Float64 t) { m->time = t; }
static void handle(Model *m) { (void)m; }
#elif defined(MODEL_STAIR)
static fmi3Float64 next_event(const Model *m) { return (floor(m->time / m->period + 1e-9) + 1.0) * m->period; }
static void advance(Model *m, fmi3Float64 t) { m->time = t; }
static void handle(Model *m) { m->counter += 1; }
#else
static fmi3Float64 next_event(const Model *m) {
    if (m->resting) return INFINITY;
    /* h + v s - g s^2 / 2 = 0, the positive root (h >= 0) */
    fmi3Float64 s = (m->v + sqrt(m->v * m->v + 2.0 * m->g * m->h)) / m->g;
    return m->time + s;
}
static void advance(Model *m, fmi3Float64 t) {
    if (!m->resting) {
        fmi3Float64 s = t - m->time;
        m->h = m->h + m->v * s - 0.5 * m->g * s * s;
        m->v = m->v - m->g * s;
    }
    m->time = t;
}
static void handle(Model *m) {
    m->h = 0.0;
    m->v = -m->e * m->v;
    if (m->v < m->v_min) { m->v = 0.0; m->resting = fmi3True; }
}
#endif

fmi3Instance fmi3InstantiateCoSimulation(fmi3String instanceName, fmi3String instantiationToken,
                                         fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                         fmi3Boolean eventModeUsed, fmi3Boolean earlyReturnAllowed,
                                         const fmi3ValueReference requiredIntermediateVariables[],
                                         size_t nRequiredIntermediateVariables,
                                         fmi3InstanceEnvironment instanceEnvironment,
                                         fmi3LogMessageCallback logMessage,
                                         fmi3IntermediateUpdateCallback intermediateUpdate) {
    (void)instanceName; (void)instantiationToken; (void)resourcePath; (void)visible; (void)loggingOn;
    (void)requiredIntermediateVariables; (void)nRequiredIntermediateVariables; (void)instanceEnvironment;
    (void)logMessage; (void)intermediateUpdate;
    Model *m = calloc(1, sizeof(Model));
    if (!m) return NULL;
    m->event_mode = eventModeUsed;
    m->early_return = earlyReturnAllowed;
    m->period = 1.0;
    m->g = 9.81; m->e = 0.7; m->h0 = 1.0; m->v_min = 0.1;
    return m;
}

void fmi3FreeInstance(fmi3Instance instance) { free(instance); }

fmi3Status fmi3EnterInitializationMode(fmi3Instance instance, fmi3Boolean toleranceDefined, fmi3Float64 tolerance,
                                       fmi3Float64 startTime, fmi3Boolean stopTimeDefined, fmi3Float64 stopTime) {
    (void)toleranceDefined; (void)tolerance; (void)stopTimeDefined; (void)stopTime;
    ((Model *)instance)->time = startTime;
    return fmi3OK;
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance instance) {
    Model *m = instance;
    m->h = m->h0; m->v = 0.0; m->counter = 0; m->resting = fmi3False;
    return m->period > 0.0 && m->g > 0.0 ? fmi3OK : fmi3Error;
}

fmi3Status fmi3EnterEventMode(fmi3Instance instance) { (void)instance; return fmi3OK; }

fmi3Status fmi3UpdateDiscreteStates(fmi3Instance instance, fmi3Boolean *discreteStatesNeedUpdate,
                                    fmi3Boolean *terminateSimulation, fmi3Boolean *nominalsChanged,
                                    fmi3Boolean *valuesChanged, fmi3Boolean *nextEventTimeDefined,
                                    fmi3Float64 *nextEventTime) {
    Model *m = instance;
    if (m->pending) { handle(m); m->pending = fmi3False; }
    if (m->tick) { m->counter += 1; m->last_tick = m->time; m->tick = fmi3False; }  /* deactivated when handled */
    *discreteStatesNeedUpdate = fmi3False; *terminateSimulation = fmi3False; *nominalsChanged = fmi3False;
    *valuesChanged = fmi3True;
#if defined(MODEL_STAIR)
    *nextEventTimeDefined = fmi3True;
    *nextEventTime = next_event(m);
#else
    *nextEventTimeDefined = fmi3False;  /* a state event: its time is not known in advance */
    *nextEventTime = 0.0;
#endif
    return fmi3OK;
}

fmi3Status fmi3EnterStepMode(fmi3Instance instance) { (void)instance; return fmi3OK; }

fmi3Status fmi3DoStep(fmi3Instance instance, fmi3Float64 currentCommunicationPoint,
                      fmi3Float64 communicationStepSize, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                      fmi3Boolean *eventHandlingNeeded, fmi3Boolean *terminateSimulation, fmi3Boolean *earlyReturn,
                      fmi3Float64 *lastSuccessfulTime) {
    (void)noSetFMUStatePriorToCurrentPoint;
    Model *m = instance;
    const fmi3Float64 end = currentCommunicationPoint + communicationStepSize;
    *eventHandlingNeeded = fmi3False; *terminateSimulation = fmi3False; *earlyReturn = fmi3False;
    if (m->pending) return fmi3Error;  /* an event not handled: the master skipped event mode */
    m->time = currentCommunicationPoint;
    for (;;) {
        fmi3Float64 te = next_event(m);
        if (te > end) break;
        advance(m, te);
        if (m->event_mode) {  /* the master handles it: return at the event (or at the end when it is there) */
            m->pending = fmi3True;
            *eventHandlingNeeded = fmi3True;
            *earlyReturn = te < end && m->early_return;
            if (*earlyReturn || te == end) { *lastSuccessfulTime = te; return fmi3OK; }
            return fmi3Error;  /* an event inside the step, event mode without early return: not supported */
        }
        handle(m);  /* no event mode: the FMU handles its event itself, inside the step */
    }
    advance(m, end);
    *lastSuccessfulTime = end;
    return fmi3OK;
}

fmi3Status fmi3Terminate(fmi3Instance instance) { (void)instance; return fmi3OK; }
fmi3Status fmi3Reset(fmi3Instance instance) { (void)instance; return fmi3Error; }

fmi3Status fmi3GetFloat64(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, fmi3Float64 values[],
                          size_t nValues) {
    Model *m = instance;
    if (nValues != nvr) return fmi3Error;
    for (size_t i = 0; i < nvr; i++) {
        switch (vr[i]) {
        case VR_TIME: values[i] = m->time; break;
#if defined(MODEL_TASK)
        case VR_B: values[i] = m->last_tick; break;
#elif defined(MODEL_STAIR)
        case VR_B: values[i] = m->period; break;
#else
        case VR_A: values[i] = m->h; break;
        case VR_B: values[i] = m->v; break;
        case VR_C: values[i] = m->g; break;
        case VR_D: values[i] = m->e; break;
        case VR_E: values[i] = m->h0; break;
        case VR_F: values[i] = m->v_min; break;
#endif
        default: return fmi3Error;
        }
    }
    return fmi3OK;
}

fmi3Status fmi3SetFloat64(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                          const fmi3Float64 values[], size_t nValues) {
    Model *m = instance;
    if (nValues != nvr) return fmi3Error;
    for (size_t i = 0; i < nvr; i++) {
        switch (vr[i]) {
#if defined(MODEL_TASK)
#elif defined(MODEL_STAIR)
        case VR_B: m->period = values[i]; break;
#else
        case VR_C: m->g = values[i]; break;
        case VR_D: m->e = values[i]; break;
        case VR_E: m->h0 = values[i]; break;
        case VR_F: m->v_min = values[i]; break;  /* 0: it never rests, its bounces pile up (Zeno) */
#endif
        default: return fmi3Error;
        }
    }
    return fmi3OK;
}

fmi3Status fmi3GetInt32(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, fmi3Int32 values[],
                        size_t nValues) {
    Model *m = instance;
    if (nValues != nvr) return fmi3Error;
    for (size_t i = 0; i < nvr; i++) {
        if (vr[i] != VR_A) return fmi3Error;
        values[i] = m->counter;
    }
    return fmi3OK;
}

fmi3Status fmi3SetClock(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, const fmi3Clock values[]) {
    Model *m = instance;
    for (size_t i = 0; i < nvr; i++) {
#if defined(MODEL_TASK)
        if (vr[i] == VR_C) { m->tick = values[i]; continue; }
#endif
        return fmi3Error;
    }
    return fmi3OK;
}

fmi3Status fmi3GetClock(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, fmi3Clock values[]) {
    (void)instance; (void)vr; (void)values;
    return nvr == 0 ? fmi3OK : fmi3Error;  /* it has no output clocks */
}
