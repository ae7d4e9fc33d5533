/*
 * SCET strobe firmware for an ATmega328P at 16 MHz (Arduino Uno / Nano), plain avr-libc.
 *
 * Timer1 makes every pulse edge in hardware: Fast PWM with TOP = OCR1A (WGM1 = 15, prescaler 1),
 * non-inverting output on OC1B = PB2 = Arduino D10 (COM1B = 2: set at BOTTOM, cleared when
 * TCNT1 passes OCR1B). A pulse is OCR1B + 1 ticks wide and starts every OCR1A + 1 ticks; no
 * interrupt touches an edge, so the edges carry no ISR jitter (HARDWARE.md Sec. 6). Defaults:
 * 16 pulses of 1,600 ticks (100 us) every 16,636 ticks (1039.75 us), the paper's Sec. 4.2.
 *
 * Interrupts only prepare later periods:
 *   TIMER1_OVF (start of a period): the period length (OCR1A) and pulse width (OCR1B) of the
 *     coming period(s), with the fractional period trim and the queued phase shift folded in.
 *   TIMER1_COMPB (end of a pulse, the pin is low): connects OC1B for the next period or leaves
 *     it disconnected (pin held low by PORTB2 = 0): single-pulse frames (Sec. 2.4), STOP.
 *
 * OCR1A and OCR1B are double buffered on silicon (loaded at BOTTOM), so a value written in the
 * overflow interrupt of period k rules period k+1. simavr 1.6 loads them at once (period k).
 * Either way exactly one period carries a phase shift, so the train after it is displaced by the
 * same number of ticks; only the period it happens in differs (README, "Firmware").
 *
 * The serial protocol (115,200 baud 8N1, one command per line) is documented in
 * hardware/README.md; the host side is scet_hardware.strobe.
 */
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#ifndef F_CPU
#define F_CPU 16000000UL
#endif

#define PROTOCOL_VERSION 1
#define BAUD 115200UL
#define LINE_MAX 48

/* Limits, in timer ticks (62.5 ns). The overflow interrupt writes the next period's values a
 * few microseconds after BOTTOM: the pulse must outlast that (WIDTH_MIN) and the period must
 * leave the interrupts room after the pulse (GAP_MIN). */
#define WIDTH_MIN 64U
#define GAP_MIN 128U
#define PERIOD_MIN 1024UL
#define PERIOD_MAX 65000UL
#define PULSES_MAX 255U
#define TRIM_MAX 255

#ifdef SCET_SIMAVR_TRACE
/* simavr reads these from the ELF's .mmcu section (never flashed: the .hex holds .text and
 * .data only): the core, its clock, and a VCD trace of the strobe pin. */
#include <avr/avr_mcu_section.h>
AVR_MCU(F_CPU, "atmega328p");
AVR_MCU_VCD_FILE("strobe.vcd", 1000);
AVR_MCU_VCD_PORT_PIN('B', 2, "strobe");
#endif

enum { MODE_BANDED = 0, MODE_SINGLE = 1 };

/* Settings written by the main loop, read by the interrupts. */
static volatile uint16_t set_period = 16636;  /* ticks per pulse period */
static volatile uint16_t set_width = 1600;    /* ticks per pulse */
static volatile uint8_t set_pulses = 16;      /* pulse periods per frame */
static volatile uint8_t set_mode = MODE_BANDED;
static volatile int16_t set_trim = 0;         /* 1/256 tick added to every period, on average */
static volatile uint8_t set_run = 1;
static volatile int32_t phase_pending = 0;    /* ticks of phase shift not yet applied */

/* State of the interrupts. */
static volatile uint32_t periods = 0;         /* periods started since power-up */
static volatile uint32_t frames = 0;          /* frames started */
static uint8_t slot = 0;                      /* period within the frame, 0 = first */
static int16_t trim_acc = 0;
static uint16_t top_written = 0, ocr_b_written = 0;

/* The line being received, and a finished line for the main loop. */
static volatile char rx_line[LINE_MAX + 1];
static volatile uint8_t rx_len = 0, rx_overflow = 0, line_ready = 0;

static uint16_t next_top(void)
{
    int32_t top = (int32_t)set_period - 1;
    trim_acc += set_trim;
    if (trim_acc >= 256) {
        trim_acc -= 256;
        top += 1;
    } else if (trim_acc <= -256) {
        trim_acc += 256;
        top -= 1;
    }
    int32_t pend = phase_pending;
    if (pend != 0) {
        /* Apply as much of the shift as one period can take. */
        int32_t lo = (int32_t)set_width + GAP_MIN - 1 - top;   /* most negative step */
        int32_t hi = 65535L - top;                             /* most positive step */
        int32_t step = pend < lo ? lo : (pend > hi ? hi : pend);
        top += step;
        phase_pending = pend - step;
    }
    return (uint16_t)top;
}

ISR(TIMER1_OVF_vect)
{
    periods++;
    if (++slot >= set_pulses)
        slot = 0;
    if (slot == 0)
        frames++;
    uint16_t top = next_top();
    uint16_t ocr_b = set_width - 1;
    if (ocr_b != ocr_b_written || top != top_written) {
        /* OCR1B first: simavr 1.6 re-reads both compare registers only on a write to OCR1A. */
        OCR1B = ocr_b;
        OCR1A = top;
        ocr_b_written = ocr_b;
        top_written = top;
    }
}

ISR(TIMER1_COMPB_vect)
{
    /* The pulse of this period has ended. Light the next period or keep it dark. */
    uint8_t next_slot = (uint8_t)(slot + 1 >= set_pulses ? 0 : slot + 1);
    uint8_t lit = set_run && (set_mode == MODE_BANDED || next_slot == 0);
    if (lit)
        TCCR1A = _BV(COM1B1) | _BV(WGM11) | _BV(WGM10);
    else
        TCCR1A = _BV(WGM11) | _BV(WGM10);
}

ISR(USART_RX_vect)
{
    char c = UDR0;
    if (line_ready)
        return;                     /* the main loop has not taken the last line yet */
    if (c == '\n') {
        rx_line[rx_len] = 0;
        line_ready = rx_overflow ? 2 : 1;
        rx_len = 0;
        rx_overflow = 0;
    } else if (c != '\r') {
        if (rx_len < LINE_MAX)
            rx_line[rx_len++] = c;
        else
            rx_overflow = 1;
    }
}

/* Replies leave through a ring buffer emptied by the UDRE interrupt, so that the CPU sleeps
 * while a reply is on the wire (in simavr, pin changes land on instruction boundaries while the
 * CPU runs; asleep, they land on their exact cycle). */
#define TX_SIZE 128
static volatile char tx_buf[TX_SIZE];
static volatile uint8_t tx_head = 0, tx_tail = 0;

ISR(USART_UDRE_vect)
{
    if (tx_head == tx_tail) {
        UCSR0B &= ~_BV(UDRIE0);
        return;
    }
    UDR0 = tx_buf[tx_tail];
    tx_tail = (uint8_t)((tx_tail + 1) % TX_SIZE);
}

static void put_char(char c)
{
    uint8_t next = (uint8_t)((tx_head + 1) % TX_SIZE);
    while (next == tx_tail) {
        /* Buffer full: wait (asleep) for the UDRE interrupt to make room. */
        cli();
        if (next == tx_tail) {
            sleep_enable();
            sei();
            sleep_cpu();
            sleep_disable();
        }
        sei();
    }
    tx_buf[tx_head] = c;
    tx_head = next;
    UCSR0B |= _BV(UDRIE0);
}

static void put_str(const char *s)
{
    while (*s)
        put_char(*s++);
}

static void put_long(const char *key, int32_t v)
{
    char buf[12];
    put_char(' ');
    put_str(key);
    put_char('=');
    ltoa(v, buf, 10);
    put_str(buf);
}

static void put_ulong(const char *key, uint32_t v)
{
    char buf[12];
    put_char(' ');
    put_str(key);
    put_char('=');
    ultoa(v, buf, 10);
    put_str(buf);
}

static void reply_error(const char *code, const char *what)
{
    put_str("ERR ");
    put_str(code);
    put_char(' ');
    put_str(what);
    put_str("\r\n");
}

static void reply_settings(void)
{
    put_str("OK");
    put_ulong("PULSES", set_pulses);
    put_ulong("WIDTH", set_width);
    put_ulong("PERIOD", set_period);
    put_long("TRIM", set_trim);
    put_str(set_mode == MODE_SINGLE ? " MODE=SINGLE" : " MODE=BANDED");
    put_ulong("RUN", set_run);
    put_ulong("F_CPU", F_CPU);
    put_str("\r\n");
}

static void reply_count(void)
{
    cli();
    uint32_t p = periods, f = frames;
    int32_t pend = phase_pending;
    sei();
    put_str("OK");
    put_ulong("PERIODS", p);
    put_ulong("FRAMES", f);
    put_long("PENDING", pend);
    put_str("\r\n");
}

/* Parse a whole signed decimal number; 0 on failure. */
static uint8_t parse_long(const char *s, int32_t *out)
{
    char *end;
    if (!s || !*s)
        return 0;
    long v = strtol(s, &end, 10);
    if (*end != 0)
        return 0;
    *out = v;
    return 1;
}

static void do_set(char *key, char *value)
{
    int32_t v = 0;
    if (!key || !value) {
        reply_error("SYNTAX", "SET KEY VALUE");
        return;
    }
    if (!strcmp(key, "MODE")) {
        if (!strcmp(value, "BANDED"))
            set_mode = MODE_BANDED;
        else if (!strcmp(value, "SINGLE"))
            set_mode = MODE_SINGLE;
        else {
            reply_error("RANGE", "MODE BANDED|SINGLE");
            return;
        }
        reply_settings();
        return;
    }
    if (!parse_long(value, &v)) {
        reply_error("SYNTAX", "VALUE NOT AN INTEGER");
        return;
    }
    if (!strcmp(key, "PULSES")) {
        if (v < 1 || v > PULSES_MAX) {
            reply_error("RANGE", "PULSES 1..255");
            return;
        }
        cli();
        set_pulses = (uint8_t)v;
        if (slot >= set_pulses)
            slot = 0;
        sei();
    } else if (!strcmp(key, "WIDTH")) {
        if (v < (int32_t)WIDTH_MIN || v > (int32_t)set_period - (int32_t)GAP_MIN) {
            reply_error("RANGE", "WIDTH 64..PERIOD-128");
            return;
        }
        cli();
        set_width = (uint16_t)v;
        sei();
    } else if (!strcmp(key, "PERIOD")) {
        if (v < (int32_t)PERIOD_MIN || v > (int32_t)PERIOD_MAX
                || v < (int32_t)set_width + (int32_t)GAP_MIN) {
            reply_error("RANGE", "PERIOD 1024..65000 AND >= WIDTH+128");
            return;
        }
        cli();
        set_period = (uint16_t)v;
        sei();
    } else if (!strcmp(key, "TRIM")) {
        if (v < -TRIM_MAX || v > TRIM_MAX) {
            reply_error("RANGE", "TRIM -255..255");
            return;
        }
        cli();
        set_trim = (int16_t)v;
        sei();
    } else {
        reply_error("UNKNOWN", key);
        return;
    }
    reply_settings();
}

static void handle_line(char *line, uint8_t overflowed)
{
    if (overflowed) {
        reply_error("LONG", "LINE OVER 48 CHARACTERS");
        return;
    }
    for (char *p = line; *p; p++)
        if (*p >= 'a' && *p <= 'z')
            *p -= 'a' - 'A';
    char *cmd = strtok(line, " \t");
    char *arg1 = strtok(NULL, " \t");
    char *arg2 = strtok(NULL, " \t");
    char *extra = strtok(NULL, " \t");
    if (!cmd)
        return;                     /* empty line: no reply */
    if (extra) {
        reply_error("SYNTAX", "TOO MANY WORDS");
    } else if (!strcmp(cmd, "PING") && !arg1) {
        put_str("OK SCET-STROBE 1\r\n");
    } else if (!strcmp(cmd, "GET") && !arg1) {
        reply_settings();
    } else if (!strcmp(cmd, "COUNT") && !arg1) {
        reply_count();
    } else if (!strcmp(cmd, "SET")) {
        if (arg2)
            do_set(arg1, arg2);
        else
            reply_error("SYNTAX", "SET KEY VALUE");
    } else if (!strcmp(cmd, "PHASE") && arg1 && !arg2) {
        int32_t v;
        if (!parse_long(arg1, &v) || v < -1000000L || v > 1000000L) {
            reply_error("RANGE", "PHASE -1000000..1000000");
            return;
        }
        cli();
        phase_pending += v;
        int32_t pend = phase_pending;
        sei();
        put_str("OK");
        put_long("PENDING", pend);
        put_str("\r\n");
    } else if ((!strcmp(cmd, "START") || !strcmp(cmd, "STOP")) && !arg1) {
        set_run = cmd[2] == 'A';
        reply_settings();
    } else {
        reply_error("UNKNOWN", cmd);
    }
}

static void uart_init(void)
{
    /* U2X: UBRR = F_CPU / (8 BAUD) - 1 = 16 at 16 MHz, 2.1 % fast, as the Arduino core does. */
    UCSR0A = _BV(U2X0);
    UBRR0 = (uint16_t)(F_CPU / (8UL * BAUD) - 1);
    UCSR0B = _BV(RXEN0) | _BV(TXEN0) | _BV(RXCIE0);
    UCSR0C = _BV(UCSZ01) | _BV(UCSZ00);
}

static void timer_init(void)
{
    PORTB &= ~_BV(PB2);
    DDRB |= _BV(PB2);
    OCR1A = set_period - 1;
    OCR1B = set_width - 1;
    top_written = set_period - 1;
    ocr_b_written = set_width - 1;
    TCNT1 = 0;
    TIFR1 = _BV(TOV1) | _BV(OCF1B);
    TIMSK1 = _BV(TOIE1) | _BV(OCIE1B);
    TCCR1A = _BV(COM1B1) | _BV(WGM11) | _BV(WGM10);
    TCCR1B = _BV(WGM13) | _BV(WGM12) | _BV(CS10);   /* start: prescaler 1 */
}

int main(void)
{
    uart_init();
    timer_init();
    set_sleep_mode(SLEEP_MODE_IDLE);
    sei();
    put_str("READY SCET-STROBE 1\r\n");
    for (;;) {
        cli();
        if (!line_ready) {
            /* Sleep until an interrupt; sei right before sleep closes the wake-up race. */
            sleep_enable();
            sei();
            sleep_cpu();
            sleep_disable();
            continue;
        }
        sei();
        char line[LINE_MAX + 1];
        memcpy(line, (const char *)rx_line, sizeof(line));
        uint8_t overflowed = line_ready == 2;
        line_ready = 0;
        handle_line(line, overflowed);
    }
}
