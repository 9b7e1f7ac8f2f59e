/* faulty_drive: an ideal belt drive that fails on purpose (see README.md).
 *
 * Until fault_time it is an ideal drive: belt_speed = speed_setpoint.  From the first doStep that
 * starts at or after fault_time, `fault` chooses what goes wrong.  For fishfmu's tests only.
 */
#define _POSIX_C_SOURCE 200809L
#include <time.h>

#include "fmu_glue.h"

#define V(name) (inst->values[VR_##name])

enum { FAULT_NONE, FAULT_ERROR, FAULT_FATAL, FAULT_HANG, FAULT_CRASH, FAULT_NAN };

typedef struct {
    int unused;
} DriveState;

size_t model_state_size(void) { return sizeof(DriveState); }

fmi2Status model_derive(ModelInstance *inst) {
    (void)inst;
    return fmi2OK;
}

void model_start(ModelInstance *inst) {
    V(BELT_SPEED) = V(SPEED_SETPOINT);
    V(STEPS) = 0.0;
}

fmi2Status model_do_step(ModelInstance *inst, double dt_s) {
    (void)dt_s;
    if (inst->time_s >= V(FAULT_TIME) - 1e-9) {
        switch ((int)V(FAULT)) {
        case FAULT_ERROR:
            fmu_log(inst, fmi2Error, "faulty_drive: failing on purpose at t = %g s", inst->time_s);
            return fmi2Error;
        case FAULT_FATAL:
            fmu_log(inst, fmi2Fatal, "faulty_drive: fatal failure on purpose at t = %g s", inst->time_s);
            return fmi2Fatal;
        case FAULT_HANG: {
            struct timespec second = {1, 0};
            for (;;) nanosleep(&second, NULL);
        }
        case FAULT_CRASH: {
            volatile int *nowhere = NULL;
            *nowhere = 1;
            return fmi2Fatal; /* not reached */
        }
        case FAULT_NAN: {
            volatile double zero = 0.0;
            V(BELT_SPEED) = zero / zero;
            V(STEPS) += 1.0;
            return fmi2OK;
        }
        default:
            break;
        }
    }
    V(BELT_SPEED) = V(SPEED_SETPOINT);
    V(STEPS) += 1.0;
    return fmi2OK;
}
