/*
 * main.c - CTR actuator firmware: two PID position loops (1 kHz), soft
 * limits, homing, a checksummed line protocol and a link watchdog.
 * See PROTOCOL.md for the wire format and README.md for building.
 */
#include <avr/io.h>
#include <avr/interrupt.h>
#include <avr/sleep.h>
#include <avr/wdt.h>
#include <util/atomic.h>
#include <string.h>

#include "config.h"
#include "uart.h"
#include "protocol.h"
#include "motor.h"
#include "pid.h"

/* STAT flags (hex on the wire) */
#define F_HOMED     0x0001u
#define F_HOMING    0x0002u
#define F_ENABLED   0x0004u
#define F_SETTLED0  0x0008u
#define F_SETTLED1  0x0010u
#define F_WDOG      0x0020u   /* link watchdog stopped the motors       */
#define F_SWITCH    0x0040u   /* home switch pressed                    */
#define F_ENCERR    0x0080u   /* illegal encoder transition seen        */
#define F_HOMEFAIL  0x0100u   /* homing timed out                       */

enum { HOME_IDLE = 0, HOME_LEAVE, HOME_SEEK };

/* reset cause, saved before anything else runs (MCUSR must be cleared
 * early or a watchdog reset loops forever with a 15 ms timeout) */
uint8_t mcusr_saved __attribute__((section(".noinit")));
void save_mcusr(void) __attribute__((naked, used, section(".init3")));
void save_mcusr(void)
{
    mcusr_saved = MCUSR;
    MCUSR = 0;
    wdt_disable();
}

static volatile uint8_t ticks_pending;
static volatile uint32_t isr_ms;

ISR(TIMER1_COMPA_vect)
{
    isr_ms++;
    if (ticks_pending < 255)
        ticks_pending++;
}

/* microseconds since boot, 4 us resolution (Timer1 runs at 250 kHz) */
static uint32_t micros(void)
{
    uint32_t ms;
    uint8_t cnt;
    ATOMIC_BLOCK(ATOMIC_FORCEON) {
        ms = isr_ms;
        cnt = (uint8_t)TCNT1;
        if ((TIFR1 & _BV(OCF1A)) && cnt < 125)
            ms++;
    }
    return ms * 1000UL + (uint32_t)cnt * 4UL;
}

static axis_t ax[N_JOINTS];
static int32_t lim_min[N_JOINTS] = { ABS_MIN_UM, ABS_MIN_MDEG };
static int32_t lim_max[N_JOINTS] = { ABS_MAX_UM, ABS_MAX_MDEG };
static const int32_t abs_min[N_JOINTS] = { ABS_MIN_UM, ABS_MIN_MDEG };
static const int32_t abs_max[N_JOINTS] = { ABS_MAX_UM, ABS_MAX_MDEG };
static const int32_t counts_per_unit[N_JOINTS] = { COUNTS_PER_MM, COUNTS_PER_DEG };

static uint8_t homed;
static uint8_t home_state;
static uint16_t home_ms;
static uint16_t flags_sticky;      /* F_WDOG, F_HOMEFAIL */
static uint16_t link_idle_ms;
static uint32_t uptime_ms;         /* control ticks since boot                 */
static uint16_t late_ticks;
static uint16_t max_pass_us;
static uint16_t max_ctl_us;       /* longest main-loop pass (work part)       */        /* control ticks that ran late (>1 pending) */
static uint16_t frames_bad;        /* frames answered with ERR                 */
#if STATUS_PERIOD_MS > 0
static uint16_t status_ms;
#endif

/* wire unit (um or mdeg) <-> counts, rounded to nearest */
static int32_t wire_to_counts(uint8_t j, int32_t w)
{
    int32_t n = w * counts_per_unit[j];
    return (n >= 0) ? (n + 500) / 1000 : (n - 500) / 1000;
}

static int32_t counts_to_wire(uint8_t j, int32_t c)
{
    return j == 0 ? (c * J0_WIRE_PER_COUNT_NUM) >> J0_WIRE_PER_COUNT_SHIFT
                  : (c * J1_WIRE_PER_COUNT_NUM) >> J1_WIRE_PER_COUNT_SHIFT;
}

static void send(tx_frame_t *t)
{
    uart_puts(tx_finish(t));
}

static void send_simple(uint16_t seq, const char *kind)
{
    tx_frame_t t;
    tx_begin(&t, seq, kind);
    send(&t);
}

static void send_err(uint16_t seq, uint8_t code)
{
    tx_frame_t t;
    tx_begin(&t, seq, "ERR");
    tx_int(&t, code);
    tx_str(&t, proto_err_text(code));
    send(&t);
}

static uint16_t status_flags(void)
{
    uint16_t f = flags_sticky;
    if (homed) f |= F_HOMED;
    if (home_state != HOME_IDLE) f |= F_HOMING;
    if (ax[0].enabled || ax[1].enabled) f |= F_ENABLED;
    if (axis_settled(&ax[0])) f |= F_SETTLED0;
    if (axis_settled(&ax[1])) f |= F_SETTLED1;
    if (home_switch()) f |= F_SWITCH;
    if (enc_errors()) f |= F_ENCERR;
    return f;
}

static void send_stat(uint16_t seq)
{
    tx_frame_t t;
    tx_begin(&t, seq, "STAT");
    tx_int(&t, counts_to_wire(0, enc_read(0)));
    tx_int(&t, counts_to_wire(1, enc_read(1)));
    tx_hex(&t, status_flags());
    send(&t);
}

static void stop_all(void)
{
    enc_home_latch_arm(0);
    for (uint8_t j = 0; j < N_JOINTS; j++) {
        axis_disable(&ax[j]);
        motor_brake(j);
    }
    home_state = HOME_IDLE;
}

static uint8_t cmd_is(const frame_t *f, const char *name)
{
    return strcmp(f->cmd, name) == 0;
}

/* returns 0 for an unknown command */
static uint8_t dispatch(const frame_t *f)
{
    if (cmd_is(f, "HB") || cmd_is(f, "STAT")) {
        if (f->nargs) { send_err(f->seq, E_ARG); return 1; }
        send_stat(f->seq);
    } else if (cmd_is(f, "MOV")) {
        if (f->nargs != N_JOINTS) { send_err(f->seq, E_ARG); return 1; }
        for (uint8_t j = 0; j < N_JOINTS; j++) {
            if (f->args[j] < lim_min[j] || f->args[j] > lim_max[j]) {
                send_err(f->seq, E_LIMIT);
                return 1;
            }
        }
        if (home_state != HOME_IDLE) { send_err(f->seq, E_BUSY); return 1; }
        if (!homed) { send_err(f->seq, E_NOT_HOMED); return 1; }
        flags_sticky &= (uint16_t)~F_WDOG;
        for (uint8_t j = 0; j < N_JOINTS; j++) {
            axis_enable(&ax[j], enc_read(j));
            axis_set_target(&ax[j], wire_to_counts(j, f->args[j]));
        }
        send_simple(f->seq, "OK");
    } else if (cmd_is(f, "HOME")) {
        if (f->nargs) { send_err(f->seq, E_ARG); return 1; }
        stop_all();
        flags_sticky &= (uint16_t)~(F_WDOG | F_HOMEFAIL);
        homed = 0;
        /* rotation has no index sensor: the current angle becomes 0 */
        enc_write(1, 0);
        axis_enable(&ax[1], 0);
        axis_set_target(&ax[1], 0);
        home_ms = 0;
        home_state = home_switch() ? HOME_LEAVE : HOME_SEEK;
        send_simple(f->seq, "OK");
    } else if (cmd_is(f, "STOP")) {
        if (f->nargs) { send_err(f->seq, E_ARG); return 1; }
        stop_all();
        send_simple(f->seq, "OK");
    } else if (cmd_is(f, "LIM")) {
        if (f->nargs != 3 || f->args[0] < 0 || f->args[0] >= N_JOINTS) {
            send_err(f->seq, E_ARG);
            return 1;
        }
        uint8_t j = (uint8_t)f->args[0];
        int32_t lo = f->args[1], hi = f->args[2];
        if (lo >= hi || lo < abs_min[j] || hi > abs_max[j]) {
            send_err(f->seq, E_LIMIT);
            return 1;
        }
        lim_min[j] = lo;
        lim_max[j] = hi;
        send_simple(f->seq, "OK");
    } else if (cmd_is(f, "DBG")) {
        if (f->nargs) { send_err(f->seq, E_ARG); return 1; }
        tx_frame_t t;
        tx_begin(&t, f->seq, "OK");
        tx_int(&t, enc_errors());
        tx_int(&t, uart_rx_overruns());
        tx_int(&t, late_ticks);
        tx_int(&t, frames_bad);
        tx_int(&t, (int32_t)uptime_ms);
        tx_int(&t, max_pass_us);
        tx_int(&t, max_ctl_us);
        tx_int(&t, (int32_t)pcint_calls());
        send(&t);
    } else if (cmd_is(f, "VER")) {
        if (f->nargs) { send_err(f->seq, E_ARG); return 1; }
        tx_frame_t t;
        tx_begin(&t, f->seq, "OK");
        tx_str(&t, FW_VERSION);
        tx_int(&t, PROTO_VERSION);
        tx_int(&t, COUNTS_PER_MM);
        tx_int(&t, COUNTS_PER_DEG);
        send(&t);
    } else {
        send_err(f->seq, E_UNKNOWN);
        return 0;
    }
    return 1;
}

static void homing_tick(void)
{
    if (home_state == HOME_IDLE)
        return;
    if (++home_ms > HOME_TIMEOUT_MS) {
        stop_all();
        flags_sticky |= F_HOMEFAIL;
        return;
    }
    if (home_state == HOME_LEAVE) {
        if (home_switch()) {
            motor_set(0, HOME_PWM);
        } else {
            home_state = HOME_SEEK;
        }
    }
    if (home_state == HOME_SEEK) {
        enc_home_latch_arm(1);
        if (enc_home_latched()) {
            /* switch edge = insertion zero (latched in the pin-change ISR
             * at the very edge); hold it under PID */
            motor_brake(0);
            axis_enable(&ax[0], 0);
            axis_set_target(&ax[0], 0);
            enc_home_latch_arm(0);
            home_state = HOME_IDLE;
            homed = 1;
        } else {
            motor_set(0, -HOME_PWM);
        }
    }
}

static void control_tick(void)
{
    uptime_ms++;
    if (link_idle_ms < 0xFFFFu)
        link_idle_ms++;
    if (link_idle_ms >= LINK_TIMEOUT_MS &&
        (ax[0].enabled || ax[1].enabled || home_state != HOME_IDLE)) {
        stop_all();
        flags_sticky |= F_WDOG;
        tx_frame_t t;
        tx_begin(&t, 0, "WDOG");
        tx_int(&t, link_idle_ms);
        send(&t);
    }
    homing_tick();
    for (uint8_t j = 0; j < N_JOINTS; j++) {
        if (ax[j].enabled)
            motor_set(j, axis_update(&ax[j], enc_read(j)));
    }
#if STATUS_PERIOD_MS > 0
    if (++status_ms >= STATUS_PERIOD_MS) {
        status_ms = 0;
        send_stat(0);
    }
#endif
}

static void timer1_init(void)
{
    /* CTC, clk/64: 16 MHz / 64 / 250 = 1 kHz */
    TCCR1A = 0;
    TCCR1B = _BV(WGM12) | _BV(CS11) | _BV(CS10);
    OCR1A = (uint16_t)(F_CPU / 64UL / CONTROL_HZ - 1UL);
    TIMSK1 = _BV(OCIE1A);
}

int main(void)
{
    line_rx_t lr;
    frame_t f;

    motor_init();
    axis_init(&ax[0], J0_KP_Q8, J0_KI_Q16, J0_KD_Q8, J0_KFF_Q8, J0_FRIC_PWM, J0_TAU_MS,
              J0_VMAX_Q8, J0_ACC_Q8, J0_TOL_COUNTS);
    axis_init(&ax[1], J1_KP_Q8, J1_KI_Q16, J1_KD_Q8, J1_KFF_Q8, J1_FRIC_PWM, J1_TAU_MS,
              J1_VMAX_Q8, J1_ACC_Q8, J1_TOL_COUNTS);
    uart_init();
    timer1_init();
    proto_rx_init(&lr);
    set_sleep_mode(SLEEP_MODE_IDLE);
    wdt_enable(WDTO_60MS);           /* firmware hang -> MCU reset */
    sei();

    {
        tx_frame_t t;
        tx_begin(&t, 0, "READY");
        tx_str(&t, FW_VERSION);
        tx_hex(&t, mcusr_saved);
        send(&t);
    }

    for (;;) {
        wdt_reset();
        uint32_t t_pass = micros();

        /* bounded amount of input per pass keeps the loop period short */
        for (uint8_t n = 0; n < 32; n++) {
            int16_t c = uart_getc();
            if (c < 0)
                break;
            int8_t r = proto_feed(&lr, (uint8_t)c, &f);
            if (r == 1) {
                if (dispatch(&f))
                    link_idle_ms = 0;
            } else if (r < 0) {
                frames_bad++;
                send_err(f.seq, (uint8_t)(-r));
            }
        }

        uint8_t n;
        ATOMIC_BLOCK(ATOMIC_FORCEON) {
            n = ticks_pending;
            ticks_pending = 0;
        }
        if (n > 1 && late_ticks < 0xFFFFu)
            late_ticks++;
        uint32_t t_ctl = micros();
        while (n--)
            control_tick();
        uint32_t dc = micros() - t_ctl;
        if (dc > max_ctl_us) max_ctl_us = (uint16_t)dc;
        uint32_t d = micros() - t_pass;
        if (d > max_pass_us)
            max_pass_us = d > 0xFFFFu ? 0xFFFFu : (uint16_t)d;

        /* idle until the next interrupt (byte, tick, encoder edge) */
        cli();
        if (!uart_rx_available() && !ticks_pending) {
            sleep_enable();
            sei();
            sleep_cpu();
            sleep_disable();
        }
        sei();
    }
}
