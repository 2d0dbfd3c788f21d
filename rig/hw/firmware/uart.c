/* uart.c - USART0, 8N1, interrupt driven, power-of-two ring buffers. */
#include <avr/io.h>
#include <avr/interrupt.h>
#include <util/atomic.h>
#include "config.h"
#include "uart.h"

#define RX_SIZE 128u   /* must be a power of two */
#define TX_SIZE 256u

static volatile uint8_t rx_buf[RX_SIZE];
static volatile uint8_t rx_head, rx_tail;
static volatile uint8_t tx_buf[TX_SIZE];
static volatile uint8_t tx_head, tx_tail;   /* uint8_t wraps at 256 */
static volatile uint16_t rx_overruns;

void uart_init(void)
{
    /* U2X mode: UBRR = F_CPU / (8 * baud) - 1 = 16 -> 117647 baud (-2.1%),
     * the same setting the Arduino core uses for 115200. */
    const uint16_t ubrr = (uint16_t)((F_CPU + 4UL * UART_BAUD) / (8UL * UART_BAUD) - 1UL);
    /* U2X before UBRR, as the Arduino core does: simavr derives the bit
     * time when UBRR0L is written (hardware does not care) */
    UCSR0A = _BV(U2X0);
    UCSR0C = _BV(UCSZ01) | _BV(UCSZ00);          /* 8N1 */
    UBRR0H = (uint8_t)(ubrr >> 8);
    UBRR0L = (uint8_t)ubrr;
    UCSR0B = _BV(RXEN0) | _BV(TXEN0) | _BV(RXCIE0);
}

ISR(USART_RX_vect)
{
    uint8_t c = UDR0;
    uint8_t next = (uint8_t)((rx_head + 1u) & (RX_SIZE - 1u));
    if (next == rx_tail) {
        rx_overruns++;
        return;
    }
    rx_buf[rx_head] = c;
    rx_head = next;
}

ISR(USART_UDRE_vect)
{
    if (tx_head == tx_tail) {
        UCSR0B &= (uint8_t)~_BV(UDRIE0);
        return;
    }
    UDR0 = tx_buf[tx_tail];
    tx_tail = (uint8_t)(tx_tail + 1u);
}

int16_t uart_getc(void)
{
    if (rx_head == rx_tail)
        return -1;
    uint8_t c = rx_buf[rx_tail];
    rx_tail = (uint8_t)((rx_tail + 1u) & (RX_SIZE - 1u));
    return c;
}

void uart_putc(char c)
{
    uint8_t next = (uint8_t)(tx_head + 1u);
    while (next == tx_tail) {
        /* ring full: the UDRE interrupt drains it (interrupts are on in
         * the main loop, which is the only caller) */
    }
    tx_buf[tx_head] = (uint8_t)c;
    tx_head = next;
    UCSR0B |= _BV(UDRIE0);
}

void uart_puts(const char *s)
{
    while (*s)
        uart_putc(*s++);
}

uint8_t uart_rx_available(void)
{
    return rx_head != rx_tail;
}

uint16_t uart_rx_overruns(void)
{
    uint16_t v;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { v = rx_overruns; }
    return v;
}
