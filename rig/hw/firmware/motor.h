/* motor.h - H-bridge outputs (PWM + DIR + BRAKE) and quadrature encoders. */
#ifndef CTR_MOTOR_H
#define CTR_MOTOR_H
#include <stdint.h>

#define N_JOINTS 2

void motor_init(void);
/* signed duty -255..255; 0 disconnects the PWM output (true 0 %)      */
void motor_set(uint8_t j, int16_t pwm);
/* PWM 0 and short the motor terminals (dynamic brake)                  */
void motor_brake(uint8_t j);
int16_t motor_get(uint8_t j);

/* encoder counts (atomic read / write) */
int32_t enc_read(uint8_t j);
void enc_write(uint8_t j, int32_t v);
/* number of illegal A/B transitions seen (both edges at once)          */
uint16_t enc_errors(void);
uint32_t pcint_calls(void);

/* homing: while armed, the pin-change ISR zeroes joint 0's count at the
 * first edge that presses the home switch and sets the latched flag      */
void enc_home_latch_arm(uint8_t on);
uint8_t enc_home_latched(void);

/* insertion home switch, 1 = pressed */
uint8_t home_switch(void);

#endif
