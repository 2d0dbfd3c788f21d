/* uart.h - interrupt driven USART0 with RX/TX ring buffers. */
#ifndef CTR_UART_H
#define CTR_UART_H
#include <stdint.h>

void uart_init(void);
/* returns -1 when no byte is available */
int16_t uart_getc(void);
/* blocks (busy waits) while the TX ring is full */
void uart_putc(char c);
void uart_puts(const char *s);
/* 1 when at least one received byte is waiting */
uint8_t uart_rx_available(void);
/* number of RX bytes dropped because the RX ring was full */
uint16_t uart_rx_overruns(void);

#endif
