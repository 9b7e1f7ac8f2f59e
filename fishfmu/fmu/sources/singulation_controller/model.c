/* singulation_controller: PLC-style logic for a singulation line of up to 8 belts.
 *
 * Belt 1 is the infeed, belt n_belts the last one; photo-eye i sits at the discharge end of belt i.
 *
 * Scan cycle.  The logic runs in scans of scan_time T, scan k at t_start + k T.  Scan 0 runs when
 * initialization ends; doStep(t, dt) runs every scan with a time in (t, t + dt], however dt relates
 * to T (a step shorter than T may run no scan; the remainder carries over).  A scan reads the
 * inputs as last set, updates the logic and writes the outputs, which hold until the next scan.
 *
 * Start-up.  Belt i starts at (n_belts - i) * startup_delay: the last belt first, the infeed last,
 * so that the line empties downstream before fish are fed in.  A belt not yet started gets 0.
 *
 * Gap measurement (both modes).  When eye i goes from blocked to clear (a fish's tail left it), the
 * controller integrates the measured speed of the belt that carries that fish away, belt i + 1
 * (belt i itself for the last eye), over the scans while the beam stays clear.  When the beam is
 * blocked again (the next fish's head), that distance is the gap between the two fish:
 * (time since the beam cleared) x (speed of belt i + 1) when that speed is steady.
 *
 * Gap control (mode 1).  If the gap just measured at eye i < n_belts is shorter than gap_target,
 * belt i is held back at hold_factor x speed_i for hold_time (rounded to whole scans), starting at
 * the scan that saw the short gap, so that the fish behind waits while the one in front is carried
 * away; gap_events counts these holds.  A short gap during a hold restarts the hold.  The last eye
 * only measures (there is no downstream belt of ours to pull the fish away).
 *
 * Jam detection.  An eye blocked for jam_time (counted in scans from the scan that first saw it
 * blocked) raises jam, jam_belt = i (the most downstream such eye when several qualify in one
 * scan).  The jam is latched until that eye has been clear for jam_clear_time.  With jam_stop the
 * jammed belt and all belts upstream of it (1..jam_belt) get setpoint 0 while jam is raised;
 * belts downstream keep running so that they carry away what is beyond the jam.
 *
 * Priority of a belt's setpoint: not started -> 0; stopped by a jam -> 0; held -> hold_factor x
 * speed; else speed.  In mode 0 gaps are measured but never acted on.
 */
#include <math.h>

#include "fmu_glue.h"

#define MAX_BELTS 8

typedef struct {
    long scan; /* index of the last scan run */
    double start_time_s;
    int was_blocked[MAX_BELTS + 1];  /* eye state at the previous scan (index = belt number) */
    int gap_open[MAX_BELTS + 1];     /* a fish has left the eye and no next fish has arrived yet */
    double gap_travel_m[MAX_BELTS + 1];
    long blocked_since[MAX_BELTS + 1]; /* first scan that saw the eye blocked, -1 when clear */
    long clear_since[MAX_BELTS + 1];   /* first scan that saw the eye clear, -1 when blocked */
    long hold_until[MAX_BELTS + 1];    /* belt is held while scan < hold_until */
    int jam_belt;
    long gap_events;
    /* derived from the parameters */
    long start_scan[MAX_BELTS + 1];
    long hold_scans, jam_scans, jam_clear_scans;
} ControllerState;

size_t model_state_size(void) { return sizeof(ControllerState); }

#define V(name) (inst->values[VR_##name])
#define VI(name, i) (inst->values[VR_##name##_1 + (i) - 1])

/* Whole scans covering a duration, counting a duration within a millionth of a scan as reached. */
static long scans_for(double duration_s, double scan_s) { return fmu_ceil(duration_s / scan_s - 1e-6); }

fmi2Status model_derive(ModelInstance *inst) {
    ControllerState *s = (ControllerState *)inst->model;
    double scan_s = V(SCAN_TIME);
    int n = (int)V(N_BELTS), i;
    double longest_s = V(STARTUP_DELAY) * (n - 1);
    if (longest_s / scan_s > 1e9 || V(HOLD_TIME) / scan_s > 1e9 || V(JAM_TIME) / scan_s > 1e9 ||
        V(JAM_CLEAR_TIME) / scan_s > 1e9) {
        fmu_log(inst, fmi2Error, "a delay is more than 1e9 scans of scan_time = %g s", scan_s);
        return fmi2Error;
    }
    for (i = 1; i <= MAX_BELTS; i++) s->start_scan[i] = i <= n ? scans_for(V(STARTUP_DELAY) * (n - i), scan_s) : 0;
    s->hold_scans = fmu_floor(V(HOLD_TIME) / scan_s + 0.5);
    s->jam_scans = scans_for(V(JAM_TIME), scan_s);
    s->jam_clear_scans = scans_for(V(JAM_CLEAR_TIME), scan_s);
    return fmi2OK;
}

static void track_eye(ModelInstance *inst, ControllerState *s, int i, int n, long k) {
    int blocked = VI(PE, i) != 0.0;
    double carry_speed_mps = VI(BELT_SPEED, i < n ? i + 1 : i);
    if (!s->was_blocked[i] && s->gap_open[i]) s->gap_travel_m[i] += carry_speed_mps * V(SCAN_TIME);
    if (blocked && !s->was_blocked[i]) { /* a fish's head reached the eye */
        s->blocked_since[i] = k;
        s->clear_since[i] = -1;
        if (s->gap_open[i]) {
            VI(LAST_GAP_M, i) = s->gap_travel_m[i];
            s->gap_open[i] = 0;
            if ((int)V(MODE) == 1 && i < n && s->gap_travel_m[i] < V(GAP_TARGET)) {
                s->hold_until[i] = k + s->hold_scans;
                s->gap_events++;
            }
        }
    } else if (!blocked && (s->was_blocked[i] || k == 0)) { /* a fish's tail left the eye */
        s->clear_since[i] = k;
        s->blocked_since[i] = -1;
        s->gap_open[i] = s->was_blocked[i];
        s->gap_travel_m[i] = 0.0;
    }
    s->was_blocked[i] = blocked;
}

static void update_jam(ModelInstance *inst, ControllerState *s, int n, long k) {
    int i;
    if (s->jam_belt != 0) {
        long since = s->clear_since[s->jam_belt];
        if (since >= 0 && k - since >= s->jam_clear_scans) s->jam_belt = 0;
    }
    for (i = n; i >= 1 && s->jam_belt == 0; i--) {
        if (s->blocked_since[i] >= 0 && k - s->blocked_since[i] >= s->jam_scans) s->jam_belt = i;
    }
    V(JAM) = s->jam_belt != 0;
    V(JAM_BELT) = s->jam_belt;
}

static void write_setpoints(ModelInstance *inst, ControllerState *s, int n, long k) {
    int i;
    int gap_control = (int)V(MODE) == 1;
    int jam_stop = s->jam_belt != 0 && V(JAM_STOP) != 0.0;
    for (i = 1; i <= MAX_BELTS; i++) {
        int running = i <= n && k >= s->start_scan[i];
        int held = running && gap_control && k < s->hold_until[i];
        double setpoint = VI(SPEED, i);
        if (!running || (jam_stop && i <= s->jam_belt)) setpoint = 0.0;
        else if (held) setpoint *= V(HOLD_FACTOR);
        VI(SETPOINT, i) = setpoint;
        VI(HOLDING, i) = held;
    }
}

static void run_scan(ModelInstance *inst, ControllerState *s, long k) {
    int n = (int)V(N_BELTS), i;
    s->scan = k;
    for (i = 1; i <= n; i++) track_eye(inst, s, i, n, k);
    update_jam(inst, s, n, k);
    write_setpoints(inst, s, n, k);
    V(GAP_EVENTS) = (double)s->gap_events;
}

void model_start(ModelInstance *inst) {
    ControllerState *s = (ControllerState *)inst->model;
    int i;
    s->start_time_s = inst->time_s;
    s->jam_belt = 0;
    s->gap_events = 0;
    for (i = 0; i <= MAX_BELTS; i++) {
        s->was_blocked[i] = 0;
        s->gap_open[i] = 0;
        s->gap_travel_m[i] = 0.0;
        s->blocked_since[i] = -1;
        s->clear_since[i] = -1;
        s->hold_until[i] = 0;
        if (i >= 1) VI(LAST_GAP_M, i) = -1.0;
    }
    run_scan(inst, s, 0);
}

fmi2Status model_do_step(ModelInstance *inst, double dt_s) {
    ControllerState *s = (ControllerState *)inst->model;
    double elapsed_scans = (inst->time_s + dt_s - s->start_time_s) / V(SCAN_TIME);
    long last;
    if (elapsed_scans > 1e15) {
        fmu_log(inst, fmi2Error, "time %g s is beyond the scan counter", inst->time_s + dt_s);
        return fmi2Error;
    }
    last = fmu_floor(elapsed_scans + 1e-6); /* a scan due at the step's end runs in this step */
    while (s->scan < last) run_scan(inst, s, s->scan + 1);
    return fmi2OK;
}
