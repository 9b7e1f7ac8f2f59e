/* conveyor_drive: a geared induction motor on a frequency inverter driving a belt drum.
 *
 * Quantities at the motor shaft unless named otherwise; i = gear_ratio, eta_g = gear_efficiency,
 * r = drum_radius, v = belt speed = w * r / i.
 *
 * Inverter
 *   ramp reference v_ref [m/s] moves toward speed_setpoint at most ramp_acceleration a:
 *       v_ref(t + tau) = v_ref(t) + clamp(v_set - v_ref(t), -a tau, a tau)      (exact within a step)
 *   synchronous (output) speed w_sync = v_ref * i / r + c
 *   slip compensation c: first-order filter of the estimated slip,
 *       c' = (s_comp * T / k - c) / T_c          (s_comp = slip_compensation, T_c = ..._time)
 *
 * Motor (linear part of the torque-slip curve, V/f below base speed)
 *   k = T_N / (w_s - w_N),  T_N = P_N / w_N               (rated torque from rated power and speed)
 *   T = clamp(k (w_sync - w), -T_max, T_max),  T_max = torque_limit_factor * T_N
 *
 * Gearbox, drum, belt
 *   belt load          F = load_force + F_c * sat(v / v_eps) + c_v v      (sat = clamp to [-1, 1])
 *   at the drum        T_d = F r
 *   at the motor       T_L = T_d / (i eta_g)   when the motor drives the load (T_d w >= 0),
 *                      T_L = T_d eta_g / i     when the load drives the motor
 *   J_eq w' = T - T_L,  J_eq = J_motor + (J_drum + m_belt r^2) / i^2
 *
 * Outputs: belt_speed = v - belt_slip * load_force (the belt creeps on its drum under load; 0 by
 *   default), motor_torque = T, motor_speed = w in rpm, ramp_reference = v_ref,
 *   electrical_power = T w / eta_m when T w >= 0 (motoring), T w eta_m when braking.
 *
 * Integration: doStep(dt) takes n = ceil(dt / max_internal_step) classic RK4 steps of h = dt / n on
 * the states (w, c); the ramp reference enters as its exact piecewise-linear function of time.
 * model_derive refuses a max_internal_step for which RK4 would be unstable.
 *
 * Not modelled: field weakening above base speed, the nonlinear part of the torque-slip curve
 * beyond the torque limit, inverter losses, gear backlash, gear losses on the inertial torque.
 */
#include <math.h>

#include "fmu_glue.h"

#define RPM_TO_RAD_S (2.0 * 3.14159265358979323846 / 60.0)
#define RK4_STABILITY_LIMIT 2.5 /* |lambda h| for RK4 on the real axis is 2.78; keep a margin */

typedef struct {
    /* states */
    double ramp_ref_mps;  /* inverter ramp output, as belt speed */
    double w_motor_rad_s; /* motor shaft speed */
    double slip_comp_rad_s;
    /* derived from the parameters (model_derive) */
    double k_slip;        /* N.m per rad/s of slip */
    double torque_max_nm;
    double j_eq;          /* kg.m2 at the motor shaft */
    double mps_to_rad_s;  /* motor rad/s per m/s of belt speed = i / r */
} DriveState;

size_t model_state_size(void) { return sizeof(DriveState); }

static double clamp(double x, double lo, double hi) { return x < lo ? lo : (x > hi ? hi : x); }

#define V(name) (inst->values[VR_##name])

/* The ramp reference tau seconds after a step starting at ramp_ref0 (exact). */
static double ramp_at(const ModelInstance *inst, double ramp_ref0_mps, double tau_s) {
    double a_tau = V(RAMP_ACCELERATION) * tau_s;
    return ramp_ref0_mps + clamp(V(SPEED_SETPOINT) - ramp_ref0_mps, -a_tau, a_tau);
}

static double motor_torque(const DriveState *d, double ramp_ref_mps, double w, double c) {
    double w_sync = ramp_ref_mps * d->mps_to_rad_s + c;
    return clamp(d->k_slip * (w_sync - w), -d->torque_max_nm, d->torque_max_nm);
}

/* Load torque at the motor shaft for motor speed w. */
static double load_torque(const ModelInstance *inst, double w) {
    double r = V(DRUM_RADIUS), i = V(GEAR_RATIO), eta = V(GEAR_EFFICIENCY);
    double v = w * r / i;
    double force = V(LOAD_FORCE) + V(RUNNING_RESISTANCE_COULOMB) * clamp(v / V(RESISTANCE_SMOOTHING_SPEED), -1.0, 1.0) +
                   V(RUNNING_RESISTANCE_VISCOUS) * v;
    double t_drum = force * r;
    return (t_drum * w >= 0.0) ? t_drum / (i * eta) : t_drum * eta / i;
}

/* Derivatives of (w, c) at ramp reference ramp_ref_mps. */
static void derivatives(const ModelInstance *inst, const DriveState *d, double ramp_ref_mps, double w, double c,
                        double *dw, double *dc) {
    double torque = motor_torque(d, ramp_ref_mps, w, c);
    *dw = (torque - load_torque(inst, w)) / d->j_eq;
    *dc = (V(SLIP_COMPENSATION) * torque / d->k_slip - c) / V(SLIP_COMPENSATION_TIME);
}

static void rk4_step(const ModelInstance *inst, DriveState *d, double h) {
    double r0 = d->ramp_ref_mps, w = d->w_motor_rad_s, c = d->slip_comp_rad_s;
    double r_mid = ramp_at(inst, r0, 0.5 * h), r_end = ramp_at(inst, r0, h);
    double k1w, k1c, k2w, k2c, k3w, k3c, k4w, k4c;
    derivatives(inst, d, r0, w, c, &k1w, &k1c);
    derivatives(inst, d, r_mid, w + 0.5 * h * k1w, c + 0.5 * h * k1c, &k2w, &k2c);
    derivatives(inst, d, r_mid, w + 0.5 * h * k2w, c + 0.5 * h * k2c, &k3w, &k3c);
    derivatives(inst, d, r_end, w + h * k3w, c + h * k3c, &k4w, &k4c);
    d->w_motor_rad_s = w + h / 6.0 * (k1w + 2.0 * k2w + 2.0 * k3w + k4w);
    d->slip_comp_rad_s = c + h / 6.0 * (k1c + 2.0 * k2c + 2.0 * k3c + k4c);
    d->ramp_ref_mps = r_end;
}

static void update_outputs(ModelInstance *inst, const DriveState *d) {
    double torque = motor_torque(d, d->ramp_ref_mps, d->w_motor_rad_s, d->slip_comp_rad_s);
    double p_mech_w = torque * d->w_motor_rad_s;
    double eta_m = V(MOTOR_EFFICIENCY);
    V(BELT_SPEED) = d->w_motor_rad_s / d->mps_to_rad_s - V(BELT_SLIP) * V(LOAD_FORCE);
    V(MOTOR_TORQUE) = torque;
    V(MOTOR_SPEED) = d->w_motor_rad_s / RPM_TO_RAD_S;
    V(RAMP_REFERENCE) = d->ramp_ref_mps;
    V(ELECTRICAL_POWER) = p_mech_w >= 0.0 ? p_mech_w / eta_m : p_mech_w * eta_m;
}

fmi2Status model_derive(ModelInstance *inst) {
    DriveState *d = (DriveState *)inst->model;
    double w_rated = V(RATED_SPEED) * RPM_TO_RAD_S, w_sync = V(SYNCHRONOUS_SPEED) * RPM_TO_RAD_S;
    double r = V(DRUM_RADIUS), i = V(GEAR_RATIO), eta = V(GEAR_EFFICIENCY);
    double rated_torque, damping_max, lambda_max, h_max;

    if (!(w_rated < w_sync)) {
        fmu_log(inst, fmi2Error, "rated_speed = %g rpm must be below synchronous_speed = %g rpm (a motor has slip)",
                V(RATED_SPEED), V(SYNCHRONOUS_SPEED));
        return fmi2Error;
    }
    rated_torque = V(RATED_POWER) / w_rated;
    d->k_slip = rated_torque / (w_sync - w_rated);
    d->torque_max_nm = V(TORQUE_LIMIT_FACTOR) * rated_torque;
    d->j_eq = V(MOTOR_INERTIA) + (V(DRUM_INERTIA) + V(BELT_MASS) * r * r) / (i * i);
    d->mps_to_rad_s = i / r;
    V(RATED_TORQUE) = rated_torque;
    V(SLIP_STIFFNESS) = d->k_slip;
    V(EQUIVALENT_INERTIA) = d->j_eq;

    /* fastest pole of (w, c): slip stiffness plus the steepest load slope (regularised Coulomb) */
    damping_max = d->k_slip + (V(RUNNING_RESISTANCE_COULOMB) / V(RESISTANCE_SMOOTHING_SPEED) +
                               V(RUNNING_RESISTANCE_VISCOUS)) * r * r / (i * i * eta);
    lambda_max = damping_max / d->j_eq + 1.0 / V(SLIP_COMPENSATION_TIME);
    h_max = RK4_STABILITY_LIMIT / lambda_max;
    if (V(MAX_INTERNAL_STEP) > h_max) {
        fmu_log(inst, fmi2Error,
                "max_internal_step = %g s is too large for a stable step with these parameters (fastest time "
                "constant %g s): use at most %g s",
                V(MAX_INTERNAL_STEP), 1.0 / lambda_max, h_max);
        return fmi2Error;
    }
    return fmi2OK;
}

void model_start(ModelInstance *inst) {
    DriveState *d = (DriveState *)inst->model;
    d->ramp_ref_mps = V(INITIAL_BELT_SPEED);
    d->w_motor_rad_s = V(INITIAL_BELT_SPEED) * d->mps_to_rad_s;
    d->slip_comp_rad_s = 0.0;
    update_outputs(inst, d);
}

fmi2Status model_do_step(ModelInstance *inst, double dt_s) {
    DriveState *d = (DriveState *)inst->model;
    double steps = dt_s / V(MAX_INTERNAL_STEP);
    double h;
    long k, n;
    if (steps > 1e7) {
        fmu_log(inst, fmi2Error, "communication step %g s needs %g internal steps; raise max_internal_step", dt_s,
                steps);
        return fmi2Error;
    }
    n = fmu_ceil(steps - 1e-9); /* 1e-9: dt = k * max_internal_step gives k steps, not k + 1 */
    if (n < 1) n = 1;
    h = dt_s / (double)n;
    for (k = 0; k < n; k++) rk4_step(inst, d, h);
    if (!isfinite(d->w_motor_rad_s) || !isfinite(d->slip_comp_rad_s)) {
        fmu_log(inst, fmi2Error, "motor speed is no longer finite at t = %g s", inst->time_s + dt_s);
        return fmi2Error;
    }
    update_outputs(inst, d);
    return fmi2OK;
}
