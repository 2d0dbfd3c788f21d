/*
 * ctr_sim.c - emulator harness for the CTR actuator firmware.
 *
 * Loads rig/hw/firmware/build/ctr_actuator.elf on an emulated ATmega328P
 * (libsimavr), bridges USART0 to a pseudo terminal, and simulates the
 * electromechanics wired to the Uno exactly as on the rig
 * (see rig/hw/firmware/config.h for the pin map):
 *
 *   - two DC gear motors driven by PWM (Timer2 OC2B / OC2A) + DIR + BRAKE,
 *     first-order speed model (time constant 20 ms, small dead band),
 *   - two quadrature encoders (A/B on PD2/PD4 and PD5/PD6, 400 counts/mm
 *     and 20 counts/deg after 4x decoding), one edge at a time,
 *   - the insertion home switch on PD7 (active low, pressed for x <= 0),
 *   - hard stops on the insertion stage (-2 mm .. 125 mm).
 *
 * Simulated time is throttled to wall-clock time (option --speed).
 *
 * Host clock channel (see "clock channel" below and rig/hw/firmware/README.md):
 * a SOCK_SEQPACKET unix socket in the abstract namespace, "@ctr_sim:<pty>".
 * A host connected to it (rig/hw/arduino.py does so for a pty served by this
 * harness) leases simulated time: the simulation never runs more than
 * --lease-ms of simulated time past the host's latest lease, and a lease
 * only counts once every byte the host wrote before it has been read from
 * the pty.  So a host (or harness) that the OS does not schedule for a while
 * freezes simulated time instead of starving the firmware's link watchdog.
 * Without a connected client (or with --no-sync) the harness runs as before.
 *
 * stdout (line oriented, flushed, written non-blocking: lines are dropped
 * rather than stalling the simulation if nobody reads them):
 *   PTY <path>                 first line: the serial port to open
 *   T <us> <pos0> <pos1> <pwm0> <pwm1> <last_rx_us> <flags>
 *                              every --status-ms of simulated time;
 *                              pos = plant encoder counts (0 = home switch
 *                              edge / initial angle), pwm = signed duty
 *                              -255..255 seen at the H-bridge inputs,
 *                              last_rx_us = simulated time the last byte
 *                              from the host was handed to the UART,
 *                              flags: 1 brake0, 2 brake1, 4 home switch,
 *                              8 client connected
 *   S <us> <last_rx_us>        both PWM outputs became 0 (motors unpowered)
 *   M <us> <last_rx_us>        at least one PWM output became non-zero
 *   C <us> <0|1>               a client opened (1) / closed (0) the pty
 *   R <us> <why>               MCU reset: signal | open | internal
 *   SYNC @<name>               second line: the host clock channel
 *                              (absent with --no-sync)
 *   Q <us> <reason> ...        harness exits, with real-time lag and
 *                              clock-channel statistics
 *   X <us> <hex> / Y <us> <hex> with --trace-uart: each byte handed to /
 *                              sent by the MCU's USART
 * All other chatter (libsimavr) goes to stderr.
 *
 * Signals: SIGUSR1 resets the MCU (as the Uno's DTR line / reset button
 * would); SIGTERM / SIGINT exit.
 *
 * Note: libsimavrparts' uart_pty is not used: in simavr 1.6 it runs the
 * pty in a second thread that raises AVR IRQs without synchronisation,
 * mis-handles read() == -1 when the client closes the port (exactly the
 * "link closed" fault we test), prints on stdout and symlinks a fixed
 * /tmp/simavr-uart0 name.  The bridge below does the same job from the
 * simulation thread.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <poll.h>
#include <pty.h>
#include <signal.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/prctl.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include <sim_avr.h>
#include <sim_elf.h>
#include <sim_irq.h>
#include <sim_cycle_timers.h>
#include <avr_ioport.h>
#include <avr_extint.h>
#include <avr_uart.h>

#define F_CPU 16000000UL

/* ATmega328P data-space addresses */
#define R_DDRB   0x24
#define R_PORTB  0x25
#define R_DDRD   0x2A
#define R_PORTD  0x2B
#define R_TCCR2A 0xB0
#define R_OCR2A  0xB3
#define R_OCR2B  0xB4

/* simulation periods (cycles) */
#define PLANT_CYCLES   400u     /* 25 us   */
#define IO_CYCLES      1600u    /* 100 us  */
#define RX_CYCLES      1389u    /* one 8N1 byte at 115200 baud */

/* ------------------------------------------------------------------ */
/* options                                                            */
static double opt_speed = 1.0;      /* sim seconds per wall second, 0 = free */
static double opt_status_ms = 5.0;
static double opt_x0_mm = 10.0;
static double opt_th0_deg = 0.0;
static int opt_reset_on_open = 1;
static const char *opt_link = NULL;
static int opt_trace_uart = 0;
static int opt_sync = 1;
static double opt_lease_ms = 50.0;

/* ------------------------------------------------------------------ */
/* output                                                             */
static int out_fd = -1;
static unsigned long out_dropped;

static void emit(const char *fmt, ...)
{
    char line[256];
    va_list ap;
    va_start(ap, fmt);
    int n = vsnprintf(line, sizeof line, fmt, ap);
    va_end(ap);
    if (n <= 0)
        return;
    if (n >= (int)sizeof line)
        n = sizeof line - 1;
    ssize_t w = write(out_fd, line, (size_t)n);
    if (w != n)
        out_dropped++;
}

/* ------------------------------------------------------------------ */
/* simulation state                                                   */
static avr_t *avr;
static uint64_t cycle_base;          /* added to avr->cycle (survives resets) */
static uint64_t last_cycle_seen;

static volatile sig_atomic_t sig_reset, sig_quit;
static uint64_t last_rx_us;          /* sim time the last host byte went to the UART */
static int reset_hooked;             /* set from the avr->reset hook */
static void (*orig_reset)(avr_t *);

static inline uint64_t sim_cycles(void)
{
    return cycle_base + avr->cycle;
}

static inline uint64_t sim_us(void)
{
    return sim_cycles() / (F_CPU / 1000000UL);
}

/* ---- motors ------------------------------------------------------- */
typedef struct {
    double vmax;        /* counts/s at 100 % duty */
    double tau;         /* s */
    double tau_brake;   /* s */
    double deadband;    /* fraction of full duty */
    double xmin, xmax;  /* hard stops (counts), xmin >= xmax: none */
    double x, w;        /* position (counts), speed (counts/s) */
    int64_t enc;        /* count currently shown on the A/B pins */
    int pwm;            /* signed duty seen, -255..255 */
    int brake;
    avr_irq_t *pin_a, *pin_b;
} motor_t;

static motor_t mot[2];
static avr_irq_t *pin_switch;
static int switch_level = -1;        /* last level driven on PD7 */
static int moving_reported = 0;

/*
 * simavr re-asserts the internal pull-up level on every input pin whose
 * PORT bit is 1 each time the firmware writes PORTx, which would override
 * what our encoders / switch drive.  Declaring those pins as "external"
 * with the level we currently drive makes the pull-up lose, as it does
 * on real hardware.
 */
static uint8_t ext_mask, ext_value;

static void set_pin(avr_irq_t *irq, int level, int force)
{
    uint8_t bit = (uint8_t)(1u << irq->irq);
    ext_mask |= bit;
    if (level)
        ext_value |= bit;
    else
        ext_value &= (uint8_t)~bit;
    avr_ioport_external_t e = { .name = 'D', .mask = ext_mask, .value = ext_value };
    avr_ioctl(avr, AVR_IOCTL_IOPORT_SET_EXTERNAL('D'), &e);
    if (force)
        avr_raise_irq(irq, !level);
    avr_raise_irq(irq, level);
}

static int enc_state(int64_t n)
{
    static const int gray[4] = { 0, 1, 3, 2 };   /* (A << 1) | B */
    return gray[((n % 4) + 4) % 4];
}

static void drive_encoder_pins(motor_t *m, int force)
{
    int s = enc_state(m->enc);
    int a = (s >> 1) & 1, b = s & 1;
    set_pin(m->pin_a, a, force);
    set_pin(m->pin_b, b, force);
}

static void drive_switch_pin(int force)
{
    int pressed = mot[0].x <= 0.0;
    int level = pressed ? 0 : 1;
    if (force || level != switch_level) {
        set_pin(pin_switch, level, force);
        switch_level = level;
    }
}

/* signed duty as the H-bridge sees it */
static void read_bridge(int j, int *pwm, int *brake)
{
    const uint8_t *d = avr->data;
    int duty, dir, brk;
    if (j == 0) {           /* PWM PD3/OC2B, DIR PB4, BRAKE PB1 */
        int out = d[R_DDRD] & (1 << 3);
        if (out && (d[R_TCCR2A] & (1 << 5)))
            duty = d[R_OCR2B];
        else
            duty = (out && (d[R_PORTD] & (1 << 3))) ? 255 : 0;
        dir = ((d[R_DDRB] & d[R_PORTB]) & (1 << 4)) ? 1 : -1;
        brk = ((d[R_DDRB] & d[R_PORTB]) & (1 << 1)) ? 1 : 0;
    } else {                /* PWM PB3/OC2A, DIR PB5, BRAKE PB0 */
        int out = d[R_DDRB] & (1 << 3);
        if (out && (d[R_TCCR2A] & (1 << 7)))
            duty = d[R_OCR2A];
        else
            duty = (out && (d[R_PORTB] & (1 << 3))) ? 255 : 0;
        dir = ((d[R_DDRB] & d[R_PORTB]) & (1 << 5)) ? 1 : -1;
        brk = ((d[R_DDRB] & d[R_PORTB]) & (1 << 0)) ? 1 : 0;
    }
    if (brk)
        duty = 0;           /* the shield's brake overrides the PWM input */
    *pwm = dir * duty;
    *brake = brk;
}

static avr_cycle_count_t plant_tick(avr_t *a, avr_cycle_count_t when, void *param)
{
    (void)a; (void)param;
    const double dt = (double)PLANT_CYCLES / (double)F_CPU;
    for (int j = 0; j < 2; j++) {
        motor_t *m = &mot[j];
        read_bridge(j, &m->pwm, &m->brake);
        double u = m->pwm / 255.0;
        double tau = m->tau;
        double w_target;
        if (m->brake) {
            w_target = 0.0;
            tau = m->tau_brake;
        } else {
            double mag = fabs(u) - m->deadband;
            if (mag < 0)
                mag = 0;
            w_target = copysign(mag / (1.0 - m->deadband), u) * m->vmax;
        }
        m->w += (w_target - m->w) * dt / tau;
        m->x += m->w * dt;
        if (m->xmin < m->xmax) {
            if (m->x < m->xmin) { m->x = m->xmin; m->w = 0; }
            if (m->x > m->xmax) { m->x = m->xmax; m->w = 0; }
        }
        /* one encoder edge per tick and motor at most (40 kHz) */
        int64_t n = (int64_t)floor(m->x);
        if (n != m->enc) {
            int old = enc_state(m->enc);
            m->enc += (n > m->enc) ? 1 : -1;
            int s = enc_state(m->enc);
            if ((old ^ s) & 2)
                set_pin(m->pin_a, (s >> 1) & 1, 0);
            if ((old ^ s) & 1)
                set_pin(m->pin_b, s & 1, 0);
        }
    }
    drive_switch_pin(0);
    int moving = mot[0].pwm != 0 || mot[1].pwm != 0;
    if (moving != moving_reported) {
        emit("%c %llu %llu\n", moving ? 'M' : 'S', (unsigned long long)sim_us(),
             (unsigned long long)last_rx_us);
        moving_reported = moving;
    }
    return when + PLANT_CYCLES;
}

/* ---- pty bridge ---------------------------------------------------- */
static int pty_master = -1;
static char pty_name[128];
static int connected;
static uint64_t pty_rx_count;        /* bytes read from the pty since the client opened it */

#define QSIZE 8192u
typedef struct { uint8_t b[QSIZE]; unsigned head, tail; } queue_t;  /* free-running */
static queue_t host_to_avr, avr_to_host;
static int uart_xoff;

static unsigned q_len(const queue_t *q) { return q->head - q->tail; }
static void q_clear(queue_t *q) { q->tail = q->head; }
static int q_put(queue_t *q, uint8_t c)
{
    if (q_len(q) >= QSIZE)
        return 0;
    q->b[q->head++ % QSIZE] = c;
    return 1;
}

static avr_irq_t *uart_in_irq;

static void uart_out_hook(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)param;
    if (opt_trace_uart)
        emit("Y %llu %02x\n", (unsigned long long)sim_us(), value & 0xff);
    if (connected)
        q_put(&avr_to_host, (uint8_t)value);
    /* with no client the byte is lost, as on a closed serial port */
}

static void uart_xon_hook(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)value; (void)param;
    uart_xoff = 0;
}

static void uart_xoff_hook(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)param;
    uart_xoff = value ? 1 : 0;
}

/* hand host bytes to the USART at the line rate */
static avr_cycle_count_t rx_tick(avr_t *a, avr_cycle_count_t when, void *param)
{
    (void)a; (void)param;
    if (!uart_xoff && q_len(&host_to_avr)) {
        uint8_t c = host_to_avr.b[host_to_avr.tail++ % QSIZE];
        avr_raise_irq(uart_in_irq, c);
        last_rx_us = sim_us();
        if (opt_trace_uart)
            emit("X %llu %02x\n", (unsigned long long)last_rx_us, c);
    }
    return when + RX_CYCLES;
}

static void set_raw(int fd)
{
    struct termios t;
    if (tcgetattr(fd, &t) == 0) {
        cfmakeraw(&t);
        tcsetattr(fd, TCSANOW, &t);     /* on the master: applies to the slave */
    }
}

static void pty_open(void)
{
    int slave;
    if (openpty(&pty_master, &slave, pty_name, NULL, NULL) < 0) {
        fprintf(stderr, "ctr_sim: openpty: %s\n", strerror(errno));
        exit(1);
    }
    set_raw(pty_master);
    close(slave);                       /* we detect clients by POLLHUP */
    fcntl(pty_master, F_SETFL, fcntl(pty_master, F_GETFL) | O_NONBLOCK);
    if (opt_link) {
        unlink(opt_link);
        if (symlink(pty_name, opt_link) != 0)
            fprintf(stderr, "ctr_sim: symlink %s: %s\n", opt_link, strerror(errno));
    }
}

static void set_connected(int c)
{
    if (c == connected)
        return;
    connected = c;
    pty_rx_count = 0;
    q_clear(&host_to_avr);
    q_clear(&avr_to_host);
    emit("C %llu %d\n", (unsigned long long)sim_us(), c);
    if (c) {
        set_raw(pty_master);
        if (opt_reset_on_open)
            sig_reset = 2;              /* like the Uno's DTR auto-reset */
    }
}

/* clock channel fds (below), polled together with the pty */
static int sync_listen = -1, sync_client = -1;
static short sync_revents;

static void pty_service(void)
{
    struct pollfd pp[2] = { { .fd = pty_master, .events = POLLIN } };
    nfds_t np = 1;
    int sfd = sync_client >= 0 ? sync_client : sync_listen;
    if (sfd >= 0)
        pp[np++] = (struct pollfd){ .fd = sfd, .events = POLLIN };
    if (q_len(&avr_to_host))
        pp[0].events |= POLLOUT;
    if (poll(pp, np, 0) < 0)
        return;
    sync_revents = np > 1 ? pp[1].revents : 0;
    struct pollfd p = pp[0];
    if (p.revents & POLLIN) {
        uint8_t buf[512];
        unsigned room = QSIZE - q_len(&host_to_avr);
        if (room > sizeof buf)
            room = sizeof buf;
        if (room) {
            ssize_t n = read(pty_master, buf, room);
            if (n > 0) {
                set_connected(1);
                pty_rx_count += (uint64_t)n;
                for (ssize_t i = 0; i < n; i++)
                    q_put(&host_to_avr, buf[i]);
            } else if (n < 0 && errno == EIO) {
                set_connected(0);
            }
        }
    } else if (p.revents & POLLHUP) {
        set_connected(0);
    } else {
        set_connected(1);
    }
    if (connected && (p.revents & POLLOUT) && q_len(&avr_to_host)) {
        uint8_t buf[512];
        unsigned n = 0;
        unsigned t = avr_to_host.tail;
        while (n < sizeof buf && t != avr_to_host.head)
            buf[n++] = avr_to_host.b[t++ % QSIZE];
        ssize_t w = write(pty_master, buf, n);
        if (w > 0)
            avr_to_host.tail += (unsigned)w;
    }
}

/* ---- real-time throttle and periodic report ------------------------ */
static struct timespec wall0;
static uint64_t next_status_us;
static double max_lag_ms;

static double wall_s(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)(t.tv_sec - wall0.tv_sec) + 1e-9 * (double)(t.tv_nsec - wall0.tv_nsec);
}

static void shift_wall0(double s)        /* s >= 0: the simulation "lost" s of wall time */
{
    wall0.tv_sec += (time_t)s;
    wall0.tv_nsec += (long)((s - (double)(time_t)s) * 1e9);
    while (wall0.tv_nsec >= 1000000000L) { wall0.tv_nsec -= 1000000000L; wall0.tv_sec++; }
}

/* ---- host clock channel ("lease") ----------------------------------
 *
 * host -> harness   "L <n>"     lease: the host is running and has written
 *                               n bytes to the pty since it opened it
 * harness -> host   "H <pid> <st_dev> <st_rdev> <st_ino> <lease_us> <us>"
 *                               hello, on accept: identifies the pty (the
 *                               client checks it is the port it opened)
 *                   "T <us>"    simulated time, every 10 ms of it and at
 *                               every lease taken
 *                   "W <us>"    simulation waits for a lease (host late)
 *
 * A lease taken at simulated time t lets the simulation run to
 * t + --lease-ms.  It is taken once pty_rx_count >= n, i.e. once the
 * heartbeat the host wrote before it is in the UART queue: the firmware
 * then sees a host frame at least every lease_ms (+ the frame's line time),
 * however late the host thread runs in wall-clock time.  While no lease is
 * left the simulation waits (no simulated time passes) and keeps serving
 * the pty and the socket.  The lease binds only while both the pty and the
 * socket have a client; a lease still unmet after 0.25 s of wall time is
 * taken anyway (counted as forced: a byte-count mismatch must not hang). */
#define SYNC_REPORT_US   10000u
#define SYNC_FORCE_S     0.25

static char sync_name[160];
static uint64_t lease_end_us;
static int64_t lease_pending = -1;     /* n of the newest unmet lease, -1: none */
static double lease_pending_wall;
static uint64_t next_report_us;
static unsigned long n_leases, n_forced, n_stalls;
static double stall_total_ms, stall_max_ms;

static void sync_send(const char *fmt, ...)
{
    if (sync_client < 0)
        return;
    char msg[128];
    va_list ap;
    va_start(ap, fmt);
    int n = vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    if (n > 0)
        (void)send(sync_client, msg, (size_t)n, MSG_DONTWAIT | MSG_NOSIGNAL);
}

static void sync_open(void)
{
    sync_listen = socket(AF_UNIX, SOCK_SEQPACKET | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
    if (sync_listen < 0) {
        fprintf(stderr, "ctr_sim: clock channel: socket: %s\n", strerror(errno));
        return;
    }
    struct sockaddr_un a;
    memset(&a, 0, sizeof a);
    a.sun_family = AF_UNIX;
    snprintf(sync_name, sizeof sync_name, "ctr_sim:%s", pty_name);
    size_t len = strlen(sync_name);
    if (len + 1 > sizeof a.sun_path)
        len = sizeof a.sun_path - 1;
    memcpy(a.sun_path + 1, sync_name, len);       /* abstract: sun_path[0] = 0 */
    socklen_t alen = (socklen_t)(offsetof(struct sockaddr_un, sun_path) + 1 + len);
    if (bind(sync_listen, (struct sockaddr *)&a, alen) != 0 || listen(sync_listen, 1) != 0) {
        fprintf(stderr, "ctr_sim: clock channel @%s: %s (running without it)\n", sync_name, strerror(errno));
        close(sync_listen);
        sync_listen = -1;
    }
}

static void sync_drop_client(void)
{
    if (sync_client >= 0)
        close(sync_client);
    sync_client = -1;
    lease_pending = -1;
}

static void take_lease(int forced)
{
    lease_end_us = sim_us() + (uint64_t)(opt_lease_ms * 1000.0);
    lease_pending = -1;
    n_leases++;
    if (forced)
        n_forced++;
    sync_send("T %llu", (unsigned long long)sim_us());
}

static void sync_service(void)
{
    if (sync_listen < 0)
        return;
    short rev = sync_revents;
    sync_revents = 0;
    if (!rev)
        goto check;
    if (sync_client < 0) {
        int c = accept4(sync_listen, NULL, NULL, SOCK_NONBLOCK | SOCK_CLOEXEC);
        if (c >= 0) {
            struct stat st;
            memset(&st, 0, sizeof st);
            stat(pty_name, &st);
            sync_client = c;
            lease_pending = -1;
            lease_end_us = sim_us() + (uint64_t)(opt_lease_ms * 1000.0);
            sync_send("H %ld %llu %llu %llu %llu %llu", (long)getpid(), (unsigned long long)st.st_dev,
                      (unsigned long long)st.st_rdev, (unsigned long long)st.st_ino,
                      (unsigned long long)(opt_lease_ms * 1000.0), (unsigned long long)sim_us());
        }
        goto check;
    }
    for (;;) {
        char msg[64];
        ssize_t n = recv(sync_client, msg, sizeof msg - 1, MSG_DONTWAIT);
        if (n == 0 || (n < 0 && errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR)) {
            sync_drop_client();             /* host gone: run free (real time) */
            return;
        }
        if (n < 0)
            break;
        msg[n] = 0;
        if (msg[0] == 'L') {
            long long v = strtoll(msg + 1, NULL, 10);
            if (v >= 0) {
                if (lease_pending < 0)
                    lease_pending_wall = wall_s();
                lease_pending = v;
            }
        }
    }
check:
    if (sync_client >= 0 && lease_pending >= 0 && (!connected || pty_rx_count >= (uint64_t)lease_pending))
        take_lease(0);
}

static int lease_binds(void)
{
    return sync_client >= 0 && connected;
}

/* no lease left: wait for the host without advancing simulated time */
static void wait_for_lease(void)
{
    double t0 = wall_s();
    int waited = 0;
    while (lease_binds() && sim_us() >= lease_end_us && !sig_quit && !sig_reset) {
        if (!waited) {
            sync_send("W %llu", (unsigned long long)sim_us());
            waited = 1;
        }
        struct pollfd p[2];
        int np = 0;
        p[np++] = (struct pollfd){ .fd = sync_client, .events = POLLIN };
        short ev = 0;
        if (QSIZE - q_len(&host_to_avr) > 0)
            ev |= POLLIN;
        if (q_len(&avr_to_host))
            ev |= POLLOUT;
        if (ev)
            p[np++] = (struct pollfd){ .fd = pty_master, .events = ev };
        poll(p, (nfds_t)np, 10);
        pty_service();                  /* re-polls both without blocking */
        sync_service();
        if (lease_pending >= 0 && wall_s() - lease_pending_wall > SYNC_FORCE_S)
            take_lease(1);
    }
    if (waited) {
        double dt = wall_s() - t0;
        shift_wall0(dt);                /* the wait is not a real-time lag */
        n_stalls++;
        stall_total_ms += dt * 1e3;
        if (dt * 1e3 > stall_max_ms)
            stall_max_ms = dt * 1e3;
    }
}

static void throttle(void)
{
    if (opt_speed <= 0)
        return;
    double target = (double)sim_cycles() / (double)F_CPU / opt_speed;
    double now = wall_s();
    double ahead = target - now;
    if (ahead > 200e-6) {
        struct timespec ts = { (time_t)ahead, (long)((ahead - (double)(time_t)ahead) * 1e9) };
        nanosleep(&ts, NULL);
    } else if (ahead < -0.05) {
        /* we are slower than real time: record it and do not try to
         * catch up in a burst (keeps the simulated time steady) */
        double lag_ms = -ahead * 1e3;
        if (lag_ms > max_lag_ms)
            max_lag_ms = lag_ms;
        shift_wall0(-ahead - 0.05);
    }
}

static avr_cycle_count_t io_tick(avr_t *a, avr_cycle_count_t when, void *param)
{
    (void)a; (void)param;
    pty_service();
    sync_service();
    if (lease_binds() && sim_us() >= lease_end_us)
        wait_for_lease();
    uint64_t us = sim_us();
    if (sync_client >= 0 && us >= next_report_us) {
        sync_send("T %llu", (unsigned long long)us);
        next_report_us = us + SYNC_REPORT_US;
    }
    if (opt_status_ms > 0 && us >= next_status_us) {
        int flags = (mot[0].brake ? 1 : 0) | (mot[1].brake ? 2 : 0) |
                    (switch_level == 0 ? 4 : 0) | (connected ? 8 : 0);
        emit("T %llu %lld %lld %d %d %llu %d\n", (unsigned long long)us,
             (long long)mot[0].enc, (long long)mot[1].enc, mot[0].pwm, mot[1].pwm,
             (unsigned long long)last_rx_us, flags);
        next_status_us = us + (uint64_t)(opt_status_ms * 1000.0);
    }
    throttle();
    return when + IO_CYCLES;
}

/* ---- resets --------------------------------------------------------- */
static void reset_hook(avr_t *a)
{
    if (orig_reset)
        orig_reset(a);
    reset_hooked = 1;
}

static void arm(void)
{
    /* simavr 1.6 resets this to 1 cycle (in avr_cycle_timer_reset), which
     * makes a sleeping core advance one cycle per step: let it sleep up to
     * the next cycle timer instead (ours fire every 25 us anyway) */
    avr->run_cycle_limit = F_CPU / 1000;
    /* simavr polls INT0/INT1 pins every cycle while they are low in the
     * (reset default) low-level trigger mode, even with the interrupt
     * disabled; PD2 (encoder) and PD3 (PWM) are those pins.  The firmware
     * does not use INT0/INT1: turn the emulation artefact off (it is
     * re-enabled by every avr_reset). */
    avr_extint_set_strict_lvl_trig(avr, 0, 0);
    avr_extint_set_strict_lvl_trig(avr, 1, 0);
    avr_cycle_timer_register(avr, PLANT_CYCLES, plant_tick, NULL);
    avr_cycle_timer_register(avr, IO_CYCLES, io_tick, NULL);
    avr_cycle_timer_register(avr, RX_CYCLES, rx_tick, NULL);
}

static void after_reset(const char *why)
{
    /* avr_reset() drops every cycle timer and may rewind avr->cycle */
    if (avr->cycle < last_cycle_seen)
        cycle_base += last_cycle_seen - avr->cycle;
    last_cycle_seen = avr->cycle;
    uart_xoff = 0;
    q_clear(&host_to_avr);
    arm();
    for (int j = 0; j < 2; j++)
        drive_encoder_pins(&mot[j], 1);
    drive_switch_pin(1);
    emit("R %llu %s\n", (unsigned long long)sim_us(), why);
}

static void no_sleep(avr_t *a, avr_cycle_count_t how_long)
{
    (void)a; (void)how_long;     /* pacing is done by throttle() */
}

static void on_signal(int s)
{
    if (s == SIGUSR1)
        sig_reset = 1;
    else
        sig_quit = 1;
}

/* ------------------------------------------------------------------ */
static void usage(const char *argv0)
{
    fprintf(stderr,
            "usage: %s [options] firmware.elf\n"
            "  --speed F          simulated seconds per wall second (1 = real time, 0 = free run)\n"
            "  --status-ms MS     period of the T status lines in simulated ms (0 = off, default 5)\n"
            "  --x0-mm MM         initial insertion, mm from the home switch (default 10)\n"
            "  --th0-deg DEG      initial rotation (default 0)\n"
            "  --no-reset-on-open do not reset the MCU when a client opens the pty\n"
            "  --link PATH        also create the symlink PATH -> pty\n"
            "  --trace-uart       print every UART byte: X <us> <hex> (to the MCU), Y <us> <hex> (from it)\n"
            "  --lease-ms MS      host clock channel: simulated time a lease lets the simulation run (default 50)\n"
            "  --no-sync          no host clock channel: simulated time follows the wall clock only\n",
            argv0);
    exit(2);
}

int main(int argc, char **argv)
{
    const char *elf = NULL;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        if (!strcmp(a, "--speed") && i + 1 < argc) opt_speed = atof(argv[++i]);
        else if (!strcmp(a, "--status-ms") && i + 1 < argc) opt_status_ms = atof(argv[++i]);
        else if (!strcmp(a, "--x0-mm") && i + 1 < argc) opt_x0_mm = atof(argv[++i]);
        else if (!strcmp(a, "--th0-deg") && i + 1 < argc) opt_th0_deg = atof(argv[++i]);
        else if (!strcmp(a, "--no-reset-on-open")) opt_reset_on_open = 0;
        else if (!strcmp(a, "--link") && i + 1 < argc) opt_link = argv[++i];
        else if (!strcmp(a, "--trace-uart")) opt_trace_uart = 1;
        else if (!strcmp(a, "--no-sync")) opt_sync = 0;
        else if (!strcmp(a, "--lease-ms") && i + 1 < argc) opt_lease_ms = atof(argv[++i]);
        else if (a[0] == '-') usage(argv[0]);
        else elf = a;
    }
    if (!elf)
        usage(argv[0]);
    if (!(opt_lease_ms > 0 && opt_lease_ms < 1e6)) {
        fprintf(stderr, "ctr_sim: --lease-ms must be > 0\n");
        return 2;
    }

    /* protocol lines on the original stdout, library chatter on stderr */
    out_fd = dup(1);
    dup2(2, 1);
    fcntl(out_fd, F_SETFL, fcntl(out_fd, F_GETFL) | O_NONBLOCK);
    prctl(PR_SET_PDEATHSIG, SIGTERM);
    signal(SIGPIPE, SIG_IGN);
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigaction(SIGUSR1, &sa, NULL);
    sigaction(SIGTERM, &sa, NULL);
    sigaction(SIGINT, &sa, NULL);

    elf_firmware_t fw;
    memset(&fw, 0, sizeof fw);
    if (elf_read_firmware(elf, &fw) != 0) {
        fprintf(stderr, "ctr_sim: cannot read firmware %s\n", elf);
        return 1;
    }
    avr = avr_make_mcu_by_name("atmega328p");
    if (!avr) {
        fprintf(stderr, "ctr_sim: atmega328p not supported by this libsimavr\n");
        return 1;
    }
    avr_init(avr);
    avr->log = LOG_ERROR;
    avr_extint_set_strict_lvl_trig(avr, 0, 0);   /* see arm() */
    avr_extint_set_strict_lvl_trig(avr, 1, 0);
    avr_load_firmware(avr, &fw);
    avr->frequency = F_CPU;
    orig_reset = avr->reset;
    avr->reset = reset_hook;

    /* UART0 <-> pty */
    uint32_t f = 0;
    avr_ioctl(avr, AVR_IOCTL_UART_GET_FLAGS('0'), &f);
    f &= ~(AVR_UART_FLAG_STDIO | AVR_UART_FLAG_POLL_SLEEP);
    avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &f);
    uart_in_irq = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT),
                            uart_out_hook, NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XON),
                            uart_xon_hook, NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XOFF),
                            uart_xoff_hook, NULL);

    /* plant */
    mot[0] = (motor_t){ .vmax = 25.0 * 400, .tau = 0.020, .tau_brake = 0.005, .deadband = 0.03,
                        .xmin = -2.0 * 400, .xmax = 125.0 * 400, .x = opt_x0_mm * 400 };
    mot[1] = (motor_t){ .vmax = 360.0 * 20, .tau = 0.020, .tau_brake = 0.005, .deadband = 0.03,
                        .xmin = 0, .xmax = 0, .x = opt_th0_deg * 20 };
    mot[0].pin_a = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), 2);
    mot[0].pin_b = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), 4);
    mot[1].pin_a = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), 5);
    mot[1].pin_b = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), 6);
    pin_switch = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), 7);
    for (int j = 0; j < 2; j++) {
        mot[j].enc = (int64_t)floor(mot[j].x);
        drive_encoder_pins(&mot[j], 1);
    }
    drive_switch_pin(1);
    avr->sleep = no_sleep;

    pty_open();
    if (opt_sync)
        sync_open();            /* before the PTY line: a host may connect as soon as it reads it */
    emit("PTY %s\n", pty_name);
    if (sync_listen >= 0)
        emit("SYNC @%s\n", sync_name);

    clock_gettime(CLOCK_MONOTONIC, &wall0);
    arm();
    last_cycle_seen = avr->cycle;

    int state = cpu_Running;
    const char *why = "signal";
    unsigned long long n_run = 0, n_sleep = 0;
    for (;;) {
        state = avr_run(avr);
        n_run++;
        if (state == cpu_Sleeping)
            n_sleep++;
        if (state == cpu_Done || state == cpu_Crashed) {
            why = state == cpu_Done ? "cpu-done" : "cpu-crashed";
            break;
        }
        if (sig_reset && !reset_hooked)
            avr_reset(avr);          /* calls reset_hook() */
        if (reset_hooked) {          /* ours, or firmware-initiated (watchdog) */
            reset_hooked = 0;
            after_reset(sig_reset == 1 ? "signal" : sig_reset == 2 ? "open" : "internal");
            sig_reset = 0;
        } else {
            if (avr->cycle < last_cycle_seen)
                cycle_base += last_cycle_seen - avr->cycle;
            last_cycle_seen = avr->cycle;
        }
        if (sig_quit)
            break;
    }
    emit("Q %llu %s max_lag_ms=%.1f dropped_lines=%lu steps=%llu sleeping=%llu "
         "leases=%lu forced_leases=%lu lease_waits=%lu lease_wait_ms=%.1f max_lease_wait_ms=%.1f\n",
         (unsigned long long)sim_us(), why, max_lag_ms, out_dropped, n_run, n_sleep,
         n_leases, n_forced, n_stalls, stall_total_ms, stall_max_ms);
    sync_drop_client();
    if (sync_listen >= 0)
        close(sync_listen);
    if (opt_link)
        unlink(opt_link);
    return state == cpu_Crashed ? 3 : 0;
}
