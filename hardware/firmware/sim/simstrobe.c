/*
 * simstrobe: run the SCET strobe firmware in simavr (libsimavr 1.6) with its serial port wired
 * to a script or to a pseudo-terminal.
 *
 *   simstrobe [--until-ms T] [--send MS:LINE]... FIRMWARE.elf
 *       Script mode: simulate T ms (default 100) of the ATmega328P, typing each LINE (plus a
 *       newline) into its UART at simulated time MS; every line the firmware writes is printed
 *       as "<simulated us> <line>".
 *   simstrobe --pty LINK [--boot-ms B] [--edges FILE] [--until-ms T] FIRMWARE.elf
 *       Serial-port mode: the UART is a pseudo-terminal, LINK a symlink to it (open it with any
 *       serial program, e.g. pyserial); simulated time is paced to the wall clock, so timeouts
 *       on the host mean what they would with a real board. Runs until SIGTERM/SIGINT or T ms.
 *
 *       The board resets as an Uno does. On an Uno the ATmega16U2's USB-serial firmware drives
 *       the 328P's RESET through a 100 nF capacitor from DTR, so the board resets when DTR
 *       rises, i.e. when the host opens the port (Arduino Uno reference design, "automatic
 *       (software) reset"); the Optiboot bootloader then listens for an upload for about a
 *       second (its watchdog timeout, WATCHDOG_1S in optiboot.c) before it starts the sketch.
 *       A pseudo-terminal has no DTR line, so the harness watches the host open and close the
 *       slave device (inotify IN_OPEN / IN_CLOSE, which queue every event however quick the
 *       close-open): an open after a close with HUPCL set (the termios default: DTR dropped on the last close) is a
 *       DTR rise and resets the AVR; the host's bytes during the next B ms (default 1000) are
 *       swallowed, as the bootloader takes them, and the firmware runs from its reset vector
 *       afterwards. An open after a close with HUPCL cleared (stty -hupcl) does not reset.
 *       Output while the port is closed is lost, as on the board.
 *       SIGUSR1 resets the board in the middle of a session (a brown-out, a watchdog);
 *       SIGUSR2 unplugs and replugs it: the pseudo-terminal is replaced by a new one at LINK
 *       (the host's open port dies, as /dev/ttyACM0 does) and the board resets.
 *       --edges FILE appends the simulated cycle of every rising strobe edge (PB2) to FILE as
 *       a little-endian uint64, flushed every millisecond of simulated time.
 *
 * The firmware declares its own VCD trace (strobe.vcd in the working folder) in its .mmcu
 * section; simavr writes it, and closes it when the run ends.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <sys/inotify.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include <avr_ioport.h>
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
static int pty_master = -1;
static const char *pty_link;
static int host_open;                          /* slave fds the host holds open */
static int watch_fd = -1;                      /* inotify on the slave device */
static int dtr_high;                           /* DTR as the board sees it */
static avr_cycle_count_t boot_until;           /* the bootloader runs until this cycle */
static avr_cycle_count_t boot_cycles;
static volatile sig_atomic_t reset_requested, replug_requested;
static FILE *edges;

static void on_signal(int sig) { (void)sig; stop_requested = 1; }
static void on_reset_signal(int sig) { (void)sig; reset_requested = 1; }
static void on_replug_signal(int sig) { (void)sig; replug_requested = 1; }

static void on_strobe_pin(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)param;
    if (edges && value) {
        uint64_t c = avr->cycle;
        fwrite(&c, sizeof(c), 1, edges);
    }
}

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
        if (host_open) {                       /* no one listening: the byte is lost */
            ssize_t w = write(pty_master, &c, 1);
            (void)w;
        }
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
    /* Raw mode set once through a short-lived slave fd (before the watch starts: every open
     * the watch sees is the host's). */
    int slave = open(name, O_RDWR | O_NOCTTY);
    if (slave < 0)
        return -1;
    struct termios tio;
    tcgetattr(slave, &tio);
    cfmakeraw(&tio);
    tio.c_cflag |= HUPCL;
    tcsetattr(slave, TCSANOW, &tio);
    close(slave);
    char tmp[4096];
    snprintf(tmp, sizeof(tmp), "%s.new", link);
    unlink(tmp);
    if (symlink(name, tmp) || rename(tmp, link))
        return -1;
    fcntl(pty_master, F_SETFL, O_NONBLOCK);
    if (watch_fd >= 0)
        close(watch_fd);
    watch_fd = inotify_init1(IN_NONBLOCK);
    if (watch_fd < 0 || inotify_add_watch(watch_fd, name, IN_OPEN | IN_CLOSE) < 0)
        return -1;
    host_open = 0;
    dtr_high = 0;
    return 0;
}

static void reset_board(void);

/* The host's opens and closes since the last look, in order: DTR rises on the first open
 * (a reset when it was low) and drops on the last close when HUPCL is set. */
static void watch_host(void)
{
    char buf[4096] __attribute__((aligned(__alignof__(struct inotify_event))));
    ssize_t len;
    while ((len = read(watch_fd, buf, sizeof(buf))) > 0) {
        for (char *ptr = buf; ptr < buf + len;) {
            const struct inotify_event *ev = (const struct inotify_event *)ptr;
            if (ev->mask & IN_OPEN) {
                if (host_open++ == 0) {
                    if (!dtr_high)
                        reset_board();
                    dtr_high = 1;
                }
            } else if (ev->mask & IN_CLOSE) {
                if (host_open > 0 && --host_open == 0) {
                    struct termios tio;
                    if (tcgetattr(pty_master, &tio) || (tio.c_cflag & HUPCL))
                        dtr_high = 0;
                }
            }
            ptr += sizeof(struct inotify_event) + ev->len;
        }
    }
}

/* RESET pulled low: the core and its I/O reset, then the bootloader holds the firmware for
 * boot_cycles while it takes the host's bytes. The cycle count runs on (wall-clock pacing and
 * the traces stay continuous). */
static void reset_board(void)
{
    avr_cycle_count_t now = avr->cycle;
    avr_reset(avr);
    avr->cycle = now;
    boot_until = now + boot_cycles;
    q_head = q_tail = 0;
    out_len = 0;
}

static void usage(void)
{
    fprintf(stderr, "usage: simstrobe [--until-ms T] [--send MS:LINE]... [--pty LINK] [--boot-ms B] "
                    "[--edges FILE] FIRMWARE.elf\n");
    exit(2);
}

int main(int argc, char **argv)
{
    double until_ms = -1, boot_ms = 1000.0;
    const char *elf = NULL, *edges_path = NULL;
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
        } else if (!strcmp(argv[i], "--boot-ms") && i + 1 < argc) {
            boot_ms = atof(argv[++i]);
        } else if (!strcmp(argv[i], "--edges") && i + 1 < argc) {
            edges_path = argv[++i];
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
    boot_cycles = (avr_cycle_count_t)(boot_ms * 1e-3 * avr->frequency);
    if (edges_path) {
        edges = fopen(edges_path, "wb");
        if (!edges) {
            fprintf(stderr, "simstrobe: cannot write %s (%s)\n", edges_path, strerror(errno));
            return 1;
        }
        avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('B'), 2),
                                on_strobe_pin, NULL);
    }

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
    signal(SIGUSR1, on_reset_signal);
    signal(SIGUSR2, on_replug_signal);
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
        if (avr->cycle < boot_until) {
            avr->cycle += slice < boot_until - avr->cycle ? slice : boot_until - avr->cycle;
        } else {
            state = avr_run(avr);
            if (state == cpu_Done || state == cpu_Crashed)
                break;
        }
        while (next_send < n_sends && avr->cycle >= sends[next_send].when) {
            queue_bytes(sends[next_send].text, strlen(sends[next_send].text));
            next_send++;
        }
        if (avr->cycle < next_check)
            continue;
        next_check = avr->cycle + slice;
        if (edges)
            fflush(edges);
        if (pty_master >= 0) {
            if (reset_requested) {
                reset_requested = 0;
                reset_board();
            }
            if (replug_requested) {
                replug_requested = 0;
                close(pty_master);             /* the host's port dies */
                if (open_pty(pty_link)) {
                    fprintf(stderr, "simstrobe: cannot replug the pseudo-terminal (%s)\n", strerror(errno));
                    break;
                }
                reset_board();                 /* powered off and on again */
            }
            watch_host();
            double ahead_s = (double)avr->cycle / avr->frequency - (wall_s() - t0);
            int ms = ahead_s > 0 ? (int)(ahead_s * 1e3) : 0;
            if (!host_open) {
                if (ms > 0)                    /* the master would poll as hung up at once */
                    usleep((useconds_t)ms * 1000);
            } else {
                struct pollfd p = { .fd = pty_master, .events = POLLIN };
                if (poll(&p, 1, ms) > 0 && (p.revents & POLLIN)) {
                    char buf[256];
                    ssize_t n = read(pty_master, buf, sizeof(buf));
                    if (n > 0 && avr->cycle >= boot_until)
                        queue_bytes(buf, (size_t)n);   /* during boot the bootloader takes them */
                }
            }
        }
        feed_uart();
    }
    avr_terminate(avr);                        /* flushes and closes the VCD trace */
    if (edges)
        fclose(edges);
    if (pty_link)
        unlink(pty_link);
    if (state == cpu_Crashed) {
        fprintf(stderr, "simstrobe: the firmware crashed\n");
        return 1;
    }
    return 0;
}
