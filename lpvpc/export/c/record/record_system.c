/*
 * record_system.c -- system.h implementation of the record-player FMU of the portable SSP
 * (lpvpc.validation.ssp.build_record_fmu): it plays a recorded experiment and computes the
 * signals the validation harness computes, so that a co-simulation engine that only connects
 * outputs to inputs can run the set-up.
 *
 * The record (one sample per actuator step SYS_STEP s) is compiled in from the generated
 * record_table.h: REC_N samples of rec_command_ut, rec_command_pt (rad) and rec_torque_ut (N m,
 * the measured UT torque). State x = [k, perturbation, model torque]: the sample index k (held at
 * the last sample after the end) and the two signals computed from the inputs of the last tick.
 *
 * Inputs  u = [pt_position, ut_position, model_torque,   (rad, rad, N m)
 *              pt_velocity, ut_velocity,                 (rad/s)
 *              pt_acceleration, ut_acceleration]         (rad/s2)
 * Outputs y = [command_ut(k), command_pt(k),             (rad)
 *              load_ut = torque_ut(k),                   (N m)
 *              load_pt = torque_ut(k) + model_torque,    (N m)
 *              perturbation = d + T dv + T^2/2 da]       (rad)
 * with d, dv, da the PT - UT position, velocity and acceleration taken at the start of the last
 * tick: the position difference one tick T = SYS_STEP ahead (second-order Taylor), so at t the
 * output is the difference at t - T extrapolated to t and the model gets the perturbation at its
 * own sample time, as the harness gives it; model_torque likewise is the one taken at the start of
 * the last step. No output depends on the current inputs (no direct feedthrough): an engine that
 * passes values in dependency order within a communication point (OMSimulator) and one that
 * passes them after every step (libcosim, ECOS) give the record the same values. Before the first
 * step the perturbation is the commands' difference (the actuators start at their first command).
 * No parameters. Units SI.
 */
#include "system.h"
#include "record_table.h"

static long rec_index(const double *x)
{
    long k = (long)x[0];
    if (k < 0) k = 0;
    if (k > REC_N - 1) k = REC_N - 1;
    return k;
}

SYS_API int sys_initial_state(const double *p, double *x)
{
    (void)p;
    x[0] = 0.0;
    x[1] = rec_command_pt[0] - rec_command_ut[0]; /* the actuators start at rest at their first command */
    x[2] = 0.0;
    return 0;
}

SYS_API int sys_output(const double *x, const double *u, const double *p, double *y)
{
    long k = rec_index(x);
    (void)p;
    y[0] = rec_command_ut[k];
    y[1] = rec_command_pt[k];
    y[2] = rec_torque_ut[k];
    (void)u;
    y[3] = rec_torque_ut[k] + x[2];
    y[4] = x[1];
    return 0;
}

SYS_API int sys_update(const double *x, const double *u, const double *p, double *x_next)
{
    (void)p;
    x_next[0] = (double)(rec_index(x) < REC_N - 1 ? rec_index(x) + 1 : REC_N - 1);
    /* held in the state, not fed through: every engine's exchange order gives the same values */
    x_next[1] = (u[0] - u[1]) + SYS_STEP * (u[3] - u[4]) + 0.5 * SYS_STEP * SYS_STEP * (u[5] - u[6]);
    x_next[2] = u[2];
    return 0;
}
