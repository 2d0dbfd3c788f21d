/*
 * pid.h - per-joint trajectory generator + PID position controller.
 *
 * Everything is integer fixed point.  Positions are encoder counts; the
 * setpoint moves toward the target with a trapezoidal velocity profile
 * (Q8 counts per tick), and a PID + velocity/acceleration feed-forward
 * (first-order motor: u ~ v + tau * dv/dt) turns the
 * tracking error into a signed PWM duty (-255..255).  The integral term
 * only runs once the setpoint has arrived (no wind-up during moves), and a
 * static-friction offset is added outside a +-1 count dead zone.
 */
#ifndef CTR_PID_H
#define CTR_PID_H
#include <stdint.h>

typedef struct {
    /* gains / limits (constant after init) */
    int32_t kp_q8, ki_q16, kd_q8, kff_q8, fric, tau;
    int32_t vmax_q8, acc_q8;
    int32_t tol;
    /* state */
    int32_t target;      /* counts                         */
    int32_t sp_q8;       /* setpoint, Q8 counts            */
    int32_t v_q8;        /* setpoint velocity, Q8 / tick   */
    int32_t integ_q16;   /* integral term, Q16 PWM         */
    int32_t e_prev_q8;
    uint16_t settle;     /* consecutive ticks in tolerance */
    int32_t settle_pos;  /* position when that run started  */
    uint8_t enabled;
} axis_t;

void axis_init(axis_t *a, int32_t kp_q8, int32_t ki_q16, int32_t kd_q8,
               int32_t kff_q8, int32_t fric, int32_t tau_ticks,
               int32_t vmax_q8, int32_t acc_q8, int32_t tol);
/* start closed-loop control holding the current position */
void axis_enable(axis_t *a, int32_t pos);
void axis_disable(axis_t *a);
void axis_set_target(axis_t *a, int32_t target);
/* one control tick: returns the PWM command */
int16_t axis_update(axis_t *a, int32_t pos);
uint8_t axis_settled(const axis_t *a);

#endif
