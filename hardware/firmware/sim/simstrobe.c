/*
 * simstrobe: run the SCET strobe firmware in simavr (libsimavr 1.6) with its serial port wired
 * to a script or to a pseudo-terminal.
 *
 *   simstrobe [--until-ms T] [--send MS:LINE]... FIRMWARE.elf
 *       Script mode: simulate T ms (default 100) of the ATmega328P, typing each LINE (plus a
 *       newline) into its UART at simulated time MS; every line the firmware writes is printed
 *       as "<simulated us> <line>".
 *   simstrobe --pty LINK [--until-ms T] FIRMWARE.elf
 *       Serial-port mode: the UART is a pseudo-terminal, LINK a symlink to it (open it with any
 *       serial program, e.g. pyserial); simulated time is paced to the wall clock, so timeouts
 *       on the host mean what they would with a real board. Runs until SIGTERM/SIGINT or T ms.
 *
 * The firmware declares its own VCD trace (strobe.vcd in the working folder) in its .mmcu
 * section; simavr writes it, and closes it when the run ends.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include <avr_uart.h>
#include <sim_avr.h>
#include <sim_elf.h>
#include <sim_irq.h>

#define MAX_SENDS 64
#define QUEUE_SIZE 4096

static avr_t *avr;
static volatile sig_atomic_t stop_requested;

static struct { avr_cycle_count_t when; char text[128]; } sends[MAX_SENDS];
static int n_sends, next_send;

static char queue[QUEUE_SIZE];                 /* bytes waiting to enter the AVR's UART */
static int q_head, q_tail, uart_xon = 1;
static avr_irq_t *uart_input;

static char out_line[256];
static int out_len;
static int pty_master = -1, pty_slave = -1;

static void on_signal(int sig) { (void)sig; stop_requested = 1; }

static void queue_bytes(const char *s, size_t n)
{
    for (size_t i = 0; i < n; i++) {
        int next = (q_tail + 1) % QUEUE_SIZE;
        if (next == q_head)
            return;                            /* full: drop, as an overrun would */
        queue[q_tail] = s[i];
        q_tail = next;
    }
}

static void feed_uart(void)
{
    while (uart_xon && q_head != q_tail) {
        uint8_t c = (uint8_t)queue[q_head];
        q_head = (q_head + 1) % QUEUE_SIZE;
        avr_raise_irq(uart_input, c);
    }
}

static void on_uart_output(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)param;
    char c = (char)value;
    if (pty_master >= 0) {
        ssize_t w = write(pty_master, &c, 1);
        (void)w;
        return;
    }
    if (c == '\r')
        return;
    if (c == '\n' || out_len == (int)sizeof(out_line) - 1) {
        out_line[out_len] = 0;
        printf("%.3f %s\n", avr->cycle * 1e6 / avr->frequency, out_line);
        fflush(stdout);
        out_len = 0;
        return;
    }
    out_line[out_len++] = c;
}

static void on_xon(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)value; (void)param;
    uart_xon = 1;
    feed_uart();
}

static void on_xoff(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)value; (void)param;
    uart_xon = 0;
}

static double wall_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec + ts.tv_nsec * 1e-9;
}

static int open_pty(const char *link)
{
    pty_master = posix_openpt(O_RDWR | O_NOCTTY);
    if (pty_master < 0 || grantpt(pty_master) || unlockpt(pty_master))
        return -1;
    const char *name = ptsname(pty_master);
    if (!name)
        return -1;
    /* Hold the slave open ourselves, so the master never sees a hang-up between host sessions. */
    pty_slave = open(name, O_RDWR | O_NOCTTY);
    if (pty_slave < 0)
        return -1;
    struct termios tio;
    tcgetattr(pty_slave, &tio);
    cfmakeraw(&tio);
    tcsetattr(pty_slave, TCSANOW, &tio);
    unlink(link);
    if (symlink(name, link))
        return -1;
    fcntl(pty_master, F_SETFL, O_NONBLOCK);
    return 0;
}

static void usage(void)
{
    fprintf(stderr, "usage: simstrobe [--until-ms T] [--send MS:LINE]... [--pty LINK] FIRMWARE.elf\n");
    exit(2);
}

int main(int argc, char **argv)
{
    double until_ms = -1;
    const char *pty_link = NULL, *elf = NULL;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--until-ms") && i + 1 < argc) {
            until_ms = atof(argv[++i]);
        } else if (!strcmp(argv[i], "--send") && i + 1 < argc) {
            char *arg = argv[++i], *colon = strchr(arg, ':');
            if (!colon || n_sends == MAX_SENDS)
                usage();
            *colon = 0;
            sends[n_sends].when = (avr_cycle_count_t)(atof(arg) * 1e-3 * 16e6);
            snprintf(sends[n_sends].text, sizeof(sends[n_sends].text), "%s\n", colon + 1);
            n_sends++;
        } else if (!strcmp(argv[i], "--pty") && i + 1 < argc) {
            pty_link = argv[++i];
        } else if (argv[i][0] == '-' || elf) {
            usage();
        } else {
            elf = argv[i];
        }
    }
    if (!elf)
        usage();
    if (until_ms < 0)
        until_ms = pty_link ? 1e12 : 100.0;

    elf_firmware_t fw;
    memset(&fw, 0, sizeof(fw));
    if (elf_read_firmware(elf, &fw)) {
        fprintf(stderr, "simstrobe: cannot read %s\n", elf);
        return 1;
    }
    if (!fw.mmcu[0] || !fw.frequency) {
        fprintf(stderr, "simstrobe: %s declares no core/clock (AVR_MCU section missing)\n", elf);
        return 1;
    }
    avr = avr_make_mcu_by_name(fw.mmcu);
    if (!avr) {
        fprintf(stderr, "simstrobe: simavr has no core %s\n", fw.mmcu);
        return 1;
    }
    avr_init(avr);
    avr_load_firmware(avr, &fw);

    uint32_t flags = 0;
    avr_ioctl(avr, AVR_IOCTL_UART_GET_FLAGS('0'), &flags);
    flags &= ~(AVR_UART_FLAG_STDIO | AVR_UART_FLAG_POLL_SLEEP);
    avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);
    uart_input = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT),
                            on_uart_output, NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XON),
                            on_xon, NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XOFF),
                            on_xoff, NULL);

    if (pty_link && open_pty(pty_link)) {
        fprintf(stderr, "simstrobe: cannot create a pseudo-terminal at %s (%s)\n", pty_link,
                strerror(errno));
        return 1;
    }
    signal(SIGTERM, on_signal);
    signal(SIGINT, on_signal);
    if (pty_link) {
        printf("pty %s\n", ptsname(pty_master));
        fflush(stdout);
    }

    const avr_cycle_count_t end = (avr_cycle_count_t)(until_ms * 1e-3 * avr->frequency);
    const avr_cycle_count_t slice = avr->frequency / 1000;   /* check I/O every 1 ms simulated */
    avr_cycle_count_t next_check = 0;
    double t0 = wall_s();
    int state = cpu_Running;
    while (!stop_requested && avr->cycle < end) {
        state = avr_run(avr);
        if (state == cpu_Done || state == cpu_Crashed)
            break;
        while (next_send < n_sends && avr->cycle >= sends[next_send].when) {
            queue_bytes(sends[next_send].text, strlen(sends[next_send].text));
            next_send++;
        }
        if (avr->cycle < next_check)
            continue;
        next_check = avr->cycle + slice;
        if (pty_master >= 0) {
            double ahead_s = (double)avr->cycle / avr->frequency - (wall_s() - t0);
            struct pollfd p = { .fd = pty_master, .events = POLLIN };
            int ms = ahead_s > 0 ? (int)(ahead_s * 1e3) : 0;
            if (poll(&p, 1, ms) > 0 && (p.revents & POLLIN)) {
                char buf[256];
                ssize_t n = read(pty_master, buf, sizeof(buf));
                if (n > 0)
                    queue_bytes(buf, (size_t)n);
            }
        }
        feed_uart();
    }
    avr_terminate(avr);                        /* flushes and closes the VCD trace */
    if (pty_link)
        unlink(pty_link);
    if (state == cpu_Crashed) {
        fprintf(stderr, "simstrobe: the firmware crashed\n");
        return 1;
    }
    return 0;
}
