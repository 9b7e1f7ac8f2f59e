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
 *
 * Reject (reject_mode 1: doubles; 2: doubles and fish coming tail first; 0: off).  A camera
 * upstream of a reject device (gate, pusher) that acts at x = reject_x reports results; the fish go
 * from the camera to the device on belt reject_belt (1..8, also a belt beyond n_belts whose speed is
 * wired), whose measured speed belt_speed_<reject_belt> is v.  The controller integrates that belt's
 * travel s (m): s = 0 at scan 0, each later scan adds v x T (v as read at that scan), in every mode.
 * Reject windows are kept in travel, not in time, so that a change of belt speed between a result and
 * the fish's arrival moves the reject with the fish.
 *
 * A new result is a scan at which cam_results differs from its value at the previous scan (the value
 * at scan 0 is the reference: a result there is not new); a repeated result is never looked at again.
 * A new result calls for a reject when (reject_mode >= 1 and cam_double) or (reject_mode = 2 and
 * cam_lead_heading = -1), and cam_lead_length > 0.  It is camera_latency old: the leading fish's
 * front is now at x_front = cam_lead_x + v x camera_latency, its back cam_lead_length behind.  With
 * d = reject_x - x_front its window opens at s_open = s + d - reject_margin - v x actuator_time (the
 * device is commanded actuator_time before the front, less the margin, reaches reject_x) and closes
 * at s_close = s + d + cam_lead_length + reject_length + reject_margin (held until the back, plus the
 * margin, has passed the device's far end: reject_length is its length along the line, a gate's flap, so
 * that a fish still falling through an open gate is not caught by it closing).  A window with s_close < s already (the fish is past the device) is ignored.
 *
 * Up to 32 windows are pending, in the order scheduled.  A new window that overlaps or touches the
 * most recent pending one (s_open <= its s_close and s_close >= its s_open) is merged into it (the
 * union's ends); otherwise it is appended and reject_events counts one.  With 32 pending, a warning
 * is logged and the new window is merged into the most recent one (not counted).  A window is
 * dropped at the first scan with s_close < s; reject_mode = 0 drops them all.  reject is true at a
 * scan with s_open <= s <= s_close for a pending window (s compared to within 1e-9 m, so that the
 * rounding of the running sum costs no scan); in mode 0 it is false and no window is scheduled.
 * The reject logic runs after the setpoints in each scan and changes nothing else.  A result set
 * between two scans is read at the next one: the fish has then moved up to v x T more than assumed.
 */
#include <math.h>

#include "fmu_glue.h"

#define MAX_BELTS 8
#define MAX_WINDOWS 32          /* reject windows pending at once */
#define TRAVEL_TOLERANCE_M 1e-9 /* travel comparisons: float rounding of the running sum costs no scan */

typedef struct {
    double open_m, close_m; /* in travel s of belt reject_belt */
} RejectWindow;

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
    double travel_m;      /* s: travel of belt reject_belt since scan 0 */
    double last_results;  /* cam_results at the previous scan */
    int n_windows;
    RejectWindow windows[MAX_WINDOWS]; /* pending reject windows, in the order scheduled */
    long reject_events;
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

/* Does the camera result on the inputs call for a reject under reject_mode? */
static int result_calls_for_reject(ModelInstance *inst) {
    int mode = (int)V(REJECT_MODE);
    return (mode >= 1 && V(CAM_DOUBLE) != 0.0) || (mode == 2 && (int)V(CAM_LEAD_HEADING) == -1);
}

/* Schedule the window of the leading fish of a new result, the belt moving at v_mps. */
static void schedule_reject(ModelInstance *inst, ControllerState *s, double v_mps) {
    double length_m = V(CAM_LEAD_LENGTH);
    double front_now_m = V(CAM_LEAD_X) + v_mps * V(CAMERA_LATENCY);
    double to_go_m = V(REJECT_X) - front_now_m;
    RejectWindow w, *last = s->n_windows > 0 ? &s->windows[s->n_windows - 1] : NULL;
    int overlaps;
    w.open_m = s->travel_m + to_go_m - V(REJECT_MARGIN) - v_mps * V(ACTUATOR_TIME);
    w.close_m = s->travel_m + to_go_m + length_m + V(REJECT_LENGTH) + V(REJECT_MARGIN);
    if (w.close_m + TRAVEL_TOLERANCE_M < s->travel_m) return; /* the fish is past the device already */
    overlaps = last != NULL && w.open_m <= last->close_m + TRAVEL_TOLERANCE_M &&
               w.close_m + TRAVEL_TOLERANCE_M >= last->open_m;
    if (!overlaps && s->n_windows < MAX_WINDOWS) {
        s->windows[s->n_windows++] = w;
        s->reject_events++;
        return;
    }
    if (!overlaps)
        fmu_log(inst, fmi2Warning, "reject: %d windows are pending; the window of the fish at x = %g m is merged "
                "into the most recent one", MAX_WINDOWS, V(CAM_LEAD_X));
    if (w.open_m < last->open_m) last->open_m = w.open_m;
    if (w.close_m > last->close_m) last->close_m = w.close_m;
}

static void update_reject(ModelInstance *inst, ControllerState *s, long k) {
    double v_mps = VI(BELT_SPEED, (int)V(REJECT_BELT));
    int new_result = k > 0 && V(CAM_RESULTS) != s->last_results;
    int i, kept = 0, reject = 0;
    if (k > 0) s->travel_m += v_mps * V(SCAN_TIME);
    s->last_results = V(CAM_RESULTS);
    for (i = 0; i < s->n_windows; i++) /* drop the windows the fish has passed */
        if (s->windows[i].close_m + TRAVEL_TOLERANCE_M >= s->travel_m) s->windows[kept++] = s->windows[i];
    s->n_windows = (int)V(REJECT_MODE) == 0 ? 0 : kept;
    if (new_result && result_calls_for_reject(inst) && V(CAM_LEAD_LENGTH) > 0.0) schedule_reject(inst, s, v_mps);
    for (i = 0; i < s->n_windows && !reject; i++)
        reject = s->windows[i].open_m <= s->travel_m + TRAVEL_TOLERANCE_M &&
                 s->travel_m <= s->windows[i].close_m + TRAVEL_TOLERANCE_M;
    V(REJECT) = reject;
    V(REJECT_EVENTS) = (double)s->reject_events;
}

static void run_scan(ModelInstance *inst, ControllerState *s, long k) {
    int n = (int)V(N_BELTS), i;
    s->scan = k;
    for (i = 1; i <= n; i++) track_eye(inst, s, i, n, k);
    update_jam(inst, s, n, k);
    write_setpoints(inst, s, n, k);
    V(GAP_EVENTS) = (double)s->gap_events;
    update_reject(inst, s, k);
}

void model_start(ModelInstance *inst) {
    ControllerState *s = (ControllerState *)inst->model;
    int i;
    s->start_time_s = inst->time_s;
    s->jam_belt = 0;
    s->gap_events = 0;
    s->travel_m = 0.0;
    s->last_results = V(CAM_RESULTS);
    s->n_windows = 0;
    s->reject_events = 0;
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
