/* motor.c - see motor.h and config.h for the pin map. */
#include <avr/io.h>
#include <avr/interrupt.h>
#include <util/atomic.h>
#include "config.h"
#include "motor.h"

/* joint 0: PWM PD3/OC2B, DIR PB4, BRAKE PB1
 * joint 1: PWM PB3/OC2A, DIR PB5, BRAKE PB0 */
#define ENC_MASK ( _BV(PD2) | _BV(PD4) | _BV(PD5) | _BV(PD6) )

static volatile int32_t enc_count[N_JOINTS];
static volatile uint8_t enc_prev[N_JOINTS];
static volatile uint16_t enc_err;
static volatile uint8_t home_armed, home_latched;
static int16_t pwm_now[N_JOINTS];

/* index: (prev << 2) | now, with state = (A << 1) | B.
 * forward sequence 00 -> 01 -> 11 -> 10 -> 00 counts +1. */
static const int8_t quad_table[16] = {
    /* prev 00 */  0, +1, -1,  2,
    /* prev 01 */ -1,  0,  2, +1,
    /* prev 10 */ +1,  2,  0, -1,
    /* prev 11 */  2, -1, +1,  0,
};

static inline uint8_t enc_state(uint8_t pins, uint8_t j)
{
    if (j == 0)
        return (uint8_t)((((pins >> PD2) & 1u) << 1) | ((pins >> PD4) & 1u));
    return (uint8_t)((((pins >> PD5) & 1u) << 1) | ((pins >> PD6) & 1u));
}

static volatile uint32_t n_pcint;

uint32_t pcint_calls(void)
{
    uint32_t v;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { v = n_pcint; }
    return v;
}

ISR(PCINT2_vect)
{
    n_pcint++;
    uint8_t pins = PIND;
    for (uint8_t j = 0; j < N_JOINTS; j++) {
        uint8_t now = enc_state(pins, j);
        int8_t d = quad_table[(enc_prev[j] << 2) | now];
        if (d == 2) {
            enc_err++;
        } else {
            enc_count[j] += d;
        }
        enc_prev[j] = now;
    }
    if (home_armed && !(pins & _BV(PD7))) {
        enc_count[0] = 0;
        home_armed = 0;
        home_latched = 1;
    }
}

void enc_home_latch_arm(uint8_t on)
{
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
        if (on && !home_armed && !home_latched) {
            if (!(PIND & _BV(PD7))) {       /* already pressed */
                enc_count[0] = 0;
                home_latched = 1;
            } else {
                home_armed = 1;
            }
        } else if (!on) {
            home_armed = 0;
            home_latched = 0;
        }
    }
}

uint8_t enc_home_latched(void)
{
    return home_latched;
}

void motor_init(void)
{
    /* outputs low first: no motion during start-up */
    PORTB &= (uint8_t)~(_BV(PB0) | _BV(PB1) | _BV(PB3) | _BV(PB4) | _BV(PB5));
    PORTD &= (uint8_t)~_BV(PD3);
    DDRB |= _BV(PB0) | _BV(PB1) | _BV(PB3) | _BV(PB4) | _BV(PB5);
    DDRD |= _BV(PD3);

    /* Timer2: fast PWM (mode 3), clk/64 -> 976 Hz, outputs disconnected */
    TCCR2A = _BV(WGM21) | _BV(WGM20);
    TCCR2B = _BV(CS22);
    OCR2A = 0;
    OCR2B = 0;

    /* encoder + switch inputs with pull-ups */
    DDRD &= (uint8_t)~(ENC_MASK | _BV(PD7));
    PORTD |= ENC_MASK | _BV(PD7);

    uint8_t pins = PIND;
    enc_prev[0] = enc_state(pins, 0);
    enc_prev[1] = enc_state(pins, 1);
    PCMSK2 = ENC_MASK | _BV(PD7);
    PCIFR = _BV(PCIF2);
    PCICR |= _BV(PCIE2);
}

void motor_set(uint8_t j, int16_t pwm)
{
    if (pwm > PWM_MAX) pwm = PWM_MAX;
    if (pwm < -PWM_MAX) pwm = -PWM_MAX;
    pwm_now[j] = pwm;
    uint8_t duty = (uint8_t)(pwm < 0 ? -pwm : pwm);
    if (j == 0) {
        PORTB &= (uint8_t)~_BV(PB1);                     /* release brake */
        if (pwm < 0) PORTB &= (uint8_t)~_BV(PB4); else PORTB |= _BV(PB4);
        if (duty) {
            OCR2B = duty;
            TCCR2A |= _BV(COM2B1);
        } else {
            TCCR2A &= (uint8_t)~_BV(COM2B1);
            PORTD &= (uint8_t)~_BV(PD3);
        }
    } else {
        PORTB &= (uint8_t)~_BV(PB0);
        if (pwm < 0) PORTB &= (uint8_t)~_BV(PB5); else PORTB |= _BV(PB5);
        if (duty) {
            OCR2A = duty;
            TCCR2A |= _BV(COM2A1);
        } else {
            TCCR2A &= (uint8_t)~_BV(COM2A1);
            PORTB &= (uint8_t)~_BV(PB3);
        }
    }
}

void motor_brake(uint8_t j)
{
    motor_set(j, 0);
    PORTB |= (j == 0) ? _BV(PB1) : _BV(PB0);
}

int16_t motor_get(uint8_t j)
{
    return pwm_now[j];
}

int32_t enc_read(uint8_t j)
{
    int32_t v;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { v = enc_count[j]; }
    return v;
}

void enc_write(uint8_t j, int32_t v)
{
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { enc_count[j] = v; }
}

uint16_t enc_errors(void)
{
    uint16_t v;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { v = enc_err; }
    return v;
}

uint8_t home_switch(void)
{
    return (PIND & _BV(PD7)) ? 0 : 1;
}
