/*
 * config.h - build-time configuration of the CTR actuator firmware.
 *
 * Target: Arduino Uno (ATmega328P @ 16 MHz) + Arduino Motor Shield Rev3
 * (or any PWM + DIR + BRAKE H-bridge wired the same way), two DC gear
 * motors with quadrature encoders driving the inner tube through a capstan:
 *
 *   joint 0 = insertion of the inner tube  (wire unit: micrometre, um)
 *   joint 1 = rotation of the inner tube   (wire unit: millidegree, mdeg)
 *
 * Pin map (Arduino pin / AVR pin):
 *   joint 0 PWM   D3  / PD3 (OC2B)     joint 1 PWM   D11 / PB3 (OC2A)
 *   joint 0 DIR   D12 / PB4            joint 1 DIR   D13 / PB5
 *   joint 0 BRAKE D9  / PB1            joint 1 BRAKE D8  / PB0
 *   joint 0 ENC A D2  / PD2 (PCINT18)  joint 1 ENC A D5  / PD5 (PCINT21)
 *   joint 0 ENC B D4  / PD4 (PCINT20)  joint 1 ENC B D6  / PD6 (PCINT22)
 *   home switch (insertion, back end, active LOW, internal pull-up) D7 / PD7
 *
 * The emulator harness (rig/hw/sim/ctr_sim.c) uses the very same pin map.
 */
#ifndef CTR_CONFIG_H
#define CTR_CONFIG_H

#define FW_VERSION          "1.0.0"
#define PROTO_VERSION       1

#define UART_BAUD           115200UL

/* ---- control loop -------------------------------------------------- */
#define CONTROL_HZ          1000U      /* PID rate (Timer1 CTC)          */
#define LINK_TIMEOUT_MS     100U       /* link watchdog: stop motors     */
#define STATUS_PERIOD_MS    0U         /* unsolicited STAT period, 0=off */

/* ---- mechanics ----------------------------------------------------- */
/* encoder counts (4x decoded) per wire unit are given as rationals    */
#define COUNTS_PER_MM       400L       /* joint 0: 2.5 um per count      */
#define COUNTS_PER_DEG      20L        /* joint 1: 50 mdeg per count     */
/* the same as wire units per count = NUM / 2^SHIFT (no division needed) */
#define J0_WIRE_PER_COUNT_NUM    5L    /* 2.5 um   = 5 / 2^1  */
#define J0_WIRE_PER_COUNT_SHIFT  1
#define J1_WIRE_PER_COUNT_NUM    50L   /* 50 mdeg  = 50 / 2^0 */
#define J1_WIRE_PER_COUNT_SHIFT  0
_Static_assert(J0_WIRE_PER_COUNT_NUM * COUNTS_PER_MM == (1000L << J0_WIRE_PER_COUNT_SHIFT),
               "J0_WIRE_PER_COUNT_* does not match COUNTS_PER_MM");
_Static_assert(J1_WIRE_PER_COUNT_NUM * COUNTS_PER_DEG == (1000L << J1_WIRE_PER_COUNT_SHIFT),
               "J1_WIRE_PER_COUNT_* does not match COUNTS_PER_DEG");

/* absolute travel the firmware will ever accept (wire units).  The
 * host narrows these with the LIM command; it can never widen them. */
#define ABS_MIN_UM          0L
#define ABS_MAX_UM          120000L    /* 120 mm stroke                  */
#define ABS_MIN_MDEG        (-720000L) /* +-2 turns (cable wrap)         */
#define ABS_MAX_MDEG        720000L

/* ---- trajectory (per control tick, Q8 counts) ---------------------- */
/* joint 0: 15 mm/s = 6 counts/ms, 200 mm/s^2 = 0.08 counts/ms^2       */
#define J0_VMAX_Q8          (6L * 256)
#define J0_ACC_Q8           20L
/* joint 1: 180 deg/s = 3.6 counts/ms, 1800 deg/s^2 = 0.036 counts/ms^2 */
#define J1_VMAX_Q8          922L
#define J1_ACC_Q8           9L

/* ---- PID gains (Q8 fixed point, PWM units per count) --------------- */
#define J0_KP_Q8            200L       /* 0.78 PWM / count               */
#define J0_KI_Q16           400L       /* per count per tick, Q16        */
#define J0_KD_Q8            0L
#define J0_KFF_Q8           6528L      /* 25.5 PWM per (count/ms)        */
#define J0_FRIC_PWM         7L         /* static friction compensation   */
#define J0_TAU_MS           20L        /* motor time constant: accel FF  */
#define J1_KP_Q8            270L
#define J1_KI_Q16           530L
#define J1_KD_Q8            0L
#define J1_KFF_Q8           9067L      /* 35.4 PWM per (count/ms)        */
#define J1_FRIC_PWM         7L
#define J1_TAU_MS           20L
#define PID_I_LIMIT         80L        /* anti-windup clamp, PWM units   */
#define PWM_MAX             255

/* settled: |error| <= tolerance and drift <= tolerance/2 for SETTLE_TICKS
 * consecutive ticks                                                      */
#define J0_TOL_COUNTS       8L         /* 20 um                          */
#define J1_TOL_COUNTS       5L         /* 0.25 deg                       */
#define SETTLE_TICKS        30U

/* ---- homing --------------------------------------------------------- */
#define HOME_PWM            90         /* seek speed (open loop)         */
#define HOME_TIMEOUT_MS     20000U

#endif
