/* pid.c - see pid.h */
#include "config.h"
#include "pid.h"

#define SETTLE_CAP 60000u

void axis_init(axis_t *a, int32_t kp_q8, int32_t ki_q16, int32_t kd_q8,
               int32_t kff_q8, int32_t fric, int32_t tau_ticks,
               int32_t vmax_q8, int32_t acc_q8, int32_t tol)
{
    a->fric = fric;
    a->tau = tau_ticks;
    a->kp_q8 = kp_q8;
    a->ki_q16 = ki_q16;
    a->kd_q8 = kd_q8;
    a->kff_q8 = kff_q8;
    a->vmax_q8 = vmax_q8;
    a->acc_q8 = acc_q8;
    a->tol = tol;
    axis_disable(a);
    a->target = 0;
    a->sp_q8 = 0;
}

void axis_enable(axis_t *a, int32_t pos)
{
    if (a->enabled)
        return;
    a->target = pos;
    a->sp_q8 = pos << 8;
    a->v_q8 = 0;
    a->integ_q16 = 0;
    a->e_prev_q8 = 0;
    a->settle = 0;
    a->enabled = 1;
}

void axis_disable(axis_t *a)
{
    a->enabled = 0;
    a->v_q8 = 0;
    a->integ_q16 = 0;
    a->settle = 0;
}

void axis_set_target(axis_t *a, int32_t target)
{
    a->target = target;
    a->settle = 0;
}

/* Signed arithmetic shifts (avr-gcc: arithmetic, i.e. floor) instead of
 * divisions: a 32-bit division is a ~650-cycle library call on the AVR. */
#define ASR8(x)  ((x) >> 8)
#define ASR16(x) ((x) >> 16)

/* trapezoidal setpoint generator, one tick */
static void traj_step(axis_t *a)
{
    int32_t tgt_q8 = a->target << 8;
    int32_t rem = tgt_q8 - a->sp_q8;
    if (rem == 0) {
        a->v_q8 = 0;
        return;
    }
    int8_t dir = rem > 0 ? 1 : -1;
    int32_t arem = rem > 0 ? rem : -rem;
    int32_t vd = dir > 0 ? a->v_q8 : -a->v_q8;   /* speed toward target */
    int32_t acc = a->acc_q8;

    if (vd < 0) {                       /* moving away: brake first */
        vd += acc;
        if (vd > 0)
            vd = 0;
    } else {
        /* decelerate when the stopping distance v^2 / 2a reaches what is
         * left: arem - v <= v^2 / (2 acc), without dividing */
        if (2 * acc * (arem - vd) <= vd * vd)
            vd -= acc;
        else
            vd += acc;
        if (vd > a->vmax_q8)
            vd = a->vmax_q8;
        if (vd < acc)
            vd = acc;                   /* creep: always arrive */
        if (vd >= arem) {
            a->sp_q8 = tgt_q8;
            a->v_q8 = 0;
            return;
        }
    }
    a->v_q8 = dir > 0 ? vd : -vd;
    a->sp_q8 += a->v_q8;
}

static int32_t clamp32(int32_t v, int32_t lo, int32_t hi)
{
    return v < lo ? lo : (v > hi ? hi : v);
}

int16_t axis_update(axis_t *a, int32_t pos)
{
    if (!a->enabled)
        return 0;
    int32_t v_prev = a->v_q8;
    traj_step(a);
    int32_t acc = a->v_q8 - v_prev;

    int32_t e_q8 = clamp32(a->sp_q8 - (pos << 8), -8000L * 256, 8000L * 256);
    int32_t e = ASR8(e_q8);

    if (a->v_q8 == 0 && (e > 1 || e < -1)) {   /* conditional integration */
        a->integ_q16 += a->ki_q16 * clamp32(e, -1000, 1000);
        a->integ_q16 = clamp32(a->integ_q16, -(PID_I_LIMIT << 16), PID_I_LIMIT << 16);
    }

    int32_t u = ASR16(a->kp_q8 * e_q8) + ASR16(a->integ_q16);
    if (a->kd_q8) {
        u += ASR16(a->kd_q8 * (e_q8 - a->e_prev_q8));
    }
    a->e_prev_q8 = e_q8;
    if (a->v_q8 != 0 || acc != 0)
        u += ASR16(a->kff_q8 * (a->v_q8 + a->tau * acc));
    if (e > 1 || e < -1 || a->v_q8 != 0) {
        if (u > 0) u += a->fric;
        else if (u < 0) u -= a->fric;
    }
    u = clamp32(u, -PWM_MAX, PWM_MAX);

    /* settled: setpoint arrived, |error| <= tol and the joint did not move
     * by more than tol/2 over SETTLE_TICKS consecutive ticks */
    int32_t err_t = a->target - pos;
    if (a->v_q8 == 0 && a->sp_q8 == (a->target << 8) &&
        err_t <= a->tol && err_t >= -a->tol) {
        int32_t drift = pos - a->settle_pos;
        int32_t half = a->tol >> 1;
        if (a->settle == 0 || drift > half || drift < -half) {
            a->settle_pos = pos;
            a->settle = 1;
        } else if (a->settle < SETTLE_CAP) {
            a->settle++;
        }
    } else {
        a->settle = 0;
    }
    return (int16_t)u;
}

uint8_t axis_settled(const axis_t *a)
{
    return a->enabled && a->settle >= SETTLE_TICKS;
}
