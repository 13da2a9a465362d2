/* hexbot-simavr: one HexBot module (comm + control ATmega162 at 1 MHz) in simavr.
 *
 * The two cores run in lockstep on one time base: the one behind always steps next, and a
 * 64-cycle heartbeat bounds how far SLEEP may jump, so they stay within ~70 cycles.
 * Simulated time is cycle * 1000 ns.  Wiring: comm USART0 <-> control USART0 (4800 Bd);
 * comm USART1 -> IR multiplexer -> centre transceiver -> IR pseudo-terminal (300 Bd);
 * control USART1 <-> debug pseudo-terminal.
 *
 * Every byte into a USART travels as a frame on a "line" (receiver.c): it starts when the
 * sender's wire is free, ends one frame later, and RXC rises at its end.  The receiver
 * holds two bytes plus one in the shift register; a fourth start bit loses the shifted one
 * (DOR), as on the chip.  simavr 1.6's own 64-byte input FIFO is never used past that.  The
 * module (the cores, their images and pins, the wires, the lockstep) is module.c, which
 * the library (hexbot_lib.c) shares; the IR multiplexer's gate, the ptys, the scripts and
 * the log are the harness's own. */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <getopt.h>
#include <poll.h>
#include <pty.h>
#include <signal.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "sim_avr.h"
#include "sim_cycle_timers.h"
#include "sim_interrupts.h"
#include "avr_ioport.h"
#include "avr_uart.h"
#include "atmega162.h"
#include "hexbot_pins.h"
#include "module.h"

#define NS_PER_CYCLE (1000000000ULL / F_CPU)
#define SLICE 1000		/* cycles between pacing checks and pty polls (1 ms) */
#define HEARTBEAT 64		/* longest SLEEP jump, in cycles */
#define BEHIND_WARN_NS 100000000ULL
#define IR_PC_BAUD 300		/* the PC's side of the IR link */
#define DEBUG_PC_BAUD 4800	/* the PC's side of the debug link */

typedef struct pty {
	const char *link;
	int fd, linked;
	char slave[128];
	line_t *in;		/* bytes the PC sends go here */
	unsigned baud;
	struct { avr_cycle_count_t due; uint8_t b; } out[4096];
	size_t ohead, olen;
	unsigned long lost;	/* written with no reader, or the reader not keeping up */
} pty_t;

typedef struct event {
	avr_cycle_count_t t;
	char text[56];
} event_t;

enum { TRACE_DDR = 1, TRACE_TICK = 2 };

static struct {
	const char *elf[2], *ir_link, *debug_link, *ir_script, *debug_script, *log;
	int dip, switches, fast, verbose, hold, trace;
	int record[2];		/* the board kind each EEPROM names, 0 = none (erased) */
	double seconds;
} opt = { .record = { BOARD_KIND_COMM, BOARD_KIND_CONTROL } };

static module_t mod;			/* the two cores and their wires (module.h) */
static pty_t ir_pty = { .fd = -1, .baud = IR_PC_BAUD };
static pty_t debug_pty = { .fd = -1, .baud = DEBUG_PC_BAUD };
static FILE *logfp;
static event_t *events;
static size_t nevents, cap_events;
static unsigned long ir_side_out;
static volatile sig_atomic_t stop_signal;

/* ------------------------------------------------------------------------------------ */

static void cleanup(void)
{
	pty_t *ps[2] = { &ir_pty, &debug_pty };
	for (int i = 0; i < 2; i++) {
		char target[sizeof ps[i]->slave];
		ssize_t n;
		if (ps[i]->linked && (n = readlink(ps[i]->link, target, sizeof target - 1)) > 0) {
			target[n] = 0;
			if (!strcmp(target, ps[i]->slave))
				unlink(ps[i]->link);
		}
		ps[i]->linked = 0;
	}
	if (logfp && logfp != stdout)
		fclose(logfp);
	else if (logfp)
		fflush(logfp);
	logfp = NULL;
}

static void die(int code, const char *fmt, ...)
{
	va_list ap;
	va_start(ap, fmt);
	fputs("hexbot-simavr: ", stderr);
	vfprintf(stderr, fmt, ap);
	fputc('\n', stderr);
	va_end(ap);
	cleanup();
	exit(code);
}

void hexbot_out_of_memory(void)
{
	die(1, "out of memory");
}

static void *xrealloc(void *p, size_t n)
{
	p = realloc(p, n);
	if (!p)
		hexbot_out_of_memory();
	return p;
}

/* simavr's own messages only with --verbose: errors stay one line. */
static void quiet_logger(avr_t *avr, const int level, const char *fmt, va_list ap)
{
	(void)avr;
	if (!opt.verbose || level > LOG_WARNING)
		return;
	fputs("hexbot-simavr: simavr: ", stderr);
	vfprintf(stderr, fmt, ap);
}

/* --- the event log: kept sorted, written once both cores have passed it ----------- */

static void event(avr_cycle_count_t t, const char *fmt, ...)
{
	if (!logfp)
		return;
	if (nevents == cap_events) {
		cap_events = cap_events ? 2 * cap_events : 256;
		events = xrealloc(events, cap_events * sizeof *events);
	}
	size_t i = nevents++;
	while (i && events[i - 1].t > t) {	/* stable: equal times keep their order */
		events[i] = events[i - 1];
		i--;
	}
	events[i].t = t;
	va_list ap;
	va_start(ap, fmt);
	vsnprintf(events[i].text, sizeof events[i].text, fmt, ap);
	va_end(ap);
}

static void flush_events(avr_cycle_count_t upto)
{
	size_t i = 0;
	for (; i < nevents && events[i].t <= upto; i++)
		fprintf(logfp, "%llu %s\n", (unsigned long long)(events[i].t * NS_PER_CYCLE),
			events[i].text);
	memmove(events, events + i, (nevents - i) * sizeof *events);
	nevents -= i;
}

/* --- the IR multiplexer ------------------------------------------------------------- */

static avr_cycle_count_t ir_mux_at;	/* when the multiplexer last changed channel */
static int ir_mux_last = -1;

static int ir_channel(void)
{
	uint8_t a = mod.boards[COMM].avr->data[atmega162_port_addr('A' + PINS_IR_MUX_PORT)];
	return ((a >> PINS_IR_MUX_A) & 1) + 2 * ((a >> PINS_IR_MUX_B) & 1) +
	       4 * ((a >> PINS_IR_MUX_C) & 1);
}

/* --- lines (receiver.c): what is the harness's own ------------------------------------ */

/* IR: a byte counts only if the multiplexer is on the centre at its start bit and stayed
 * there for all of it (the model's rule, docs/protocol.md). */
static int ir_gate(line_t *l, const frame_t *f, int whole)
{
	(void)l;
	if ((whole && ir_mux_at > f->start) || ir_channel() != PINS_IR_CENTRE) {
		event(f->start, "irdrop %02x %d", f->value, ir_channel());
		return 0;
	}
	return 1;
}

static void on_overrun(line_t *l, avr_cycle_count_t at, uint8_t lost)
{
	event(at, "overrun %s %d %02x", BOARD[l->board], l->n, lost);
}

/* A byte from the PC side: it sends at its own nominal baud, 8N1. */
static void line_push_pc(line_t *l, uint8_t value, avr_cycle_count_t at, unsigned baud)
{
	avr_cycle_count_t frame = (10 * F_CPU + baud / 2) / baud;
	line_push(l, value, at, frame, (F_CPU + baud / 2) / baud);
}

/* --- pseudo-terminals ------------------------------------------------------------- */

static void pty_open(pty_t *p)
{
	int m, s;
	struct termios t;
	if (openpty(&m, &s, p->slave, NULL, NULL) < 0)
		die(2, "openpty: %s", strerror(errno));
	if (tcgetattr(s, &t) == 0) {
		cfmakeraw(&t);
		tcsetattr(s, TCSANOW, &t);
	}
	close(s);	/* so the master sees POLLHUP while nobody has the slave open */
	fcntl(m, F_SETFL, fcntl(m, F_GETFL) | O_NONBLOCK);
	fcntl(m, F_SETFD, FD_CLOEXEC);
	p->fd = m;
	if (!p->link)
		return;
	struct stat st;
	if (lstat(p->link, &st) == 0) {
		if (!S_ISLNK(st.st_mode))
			die(2, "%s exists and is not a symlink", p->link);
		unlink(p->link);
	}
	if (symlink(p->slave, p->link) < 0)
		die(2, "cannot link %s: %s", p->link, strerror(errno));
	p->linked = 1;
}

/* A byte reaches the PC when its stop bit ends. */
static void pty_queue(pty_t *p, uint8_t b, avr_cycle_count_t due)
{
	if (p->fd < 0)
		return;
	if (p->olen == sizeof p->out / sizeof p->out[0]) {
		p->lost++;
		return;
	}
	size_t i = (p->ohead + p->olen++) % (sizeof p->out / sizeof p->out[0]);
	p->out[i].due = due;
	p->out[i].b = b;
}

static void pty_flush(pty_t *p, avr_cycle_count_t now)
{
	while (p->olen && p->out[p->ohead].due <= now) {
		struct pollfd pfd = { .fd = p->fd, .events = POLLOUT };
		uint8_t b = p->out[p->ohead].b;
		/* nobody has the slave open: drop, so a later reader gets no stale bytes */
		if (poll(&pfd, 1, 0) < 0 || (pfd.revents & (POLLHUP | POLLERR)) ||
		    write(p->fd, &b, 1) != 1)
			p->lost++;
		p->ohead = (p->ohead + 1) % (sizeof p->out / sizeof p->out[0]);
		p->olen--;
	}
}

static void pty_poll(pty_t *p, avr_cycle_count_t now)
{
	uint8_t buf[256];
	ssize_t n;
	if (p->fd < 0)
		return;
	while ((n = read(p->fd, buf, sizeof buf)) > 0)	/* EIO: no slave open; EAGAIN: none */
		for (ssize_t i = 0; i < n; i++)
			line_push_pc(p->in, buf[i], now, p->baud);
}

/* --- transmitters ------------------------------------------------------------------- */

/* The core raises UART_IRQ_OUTPUT when a byte's start bit begins (it models UDR and the
 * shift register, atmega162.c), so logged times are start bits; the chip starts one
 * within a bit time of the UDR write that found the transmitter idle.  The frame occupies
 * the wire for one frame time. */
static void on_tx(avr_irq_t *irq, uint32_t value, void *param)
{
	(void)irq;
	int id = (int)(intptr_t)param >> 1, n = (int)(intptr_t)param & 1;
	avr_cycle_count_t now = mod.boards[id].avr->cycle, frame;
	uint8_t b = value & 0xFF;
	avr_cycle_count_t start = module_tx(&mod, id, n, b, &frame);	/* UART0: the other board */

	if (n == 0)
		return;
	if (id == CONTROL) {
		event(now, "debug %02x", b);
		pty_queue(&debug_pty, b, start + frame);
	} else {
		int ch = ir_channel();
		if (ch == PINS_IR_CENTRE) {
			event(now, "ir %02x", b);
			pty_queue(&ir_pty, b, start + frame);
		} else {
			ir_side_out++;
			event(now, "irside %02x %d", b, ch);
		}
	}
}

/* A PORTx (or DDRx) register of board param / 8, port param % 8, written with value: logged
 * if it changed; 1 if it did. */
static int log_register(const char *what, int ddr, void *param, uint32_t value)
{
	int id = (int)(intptr_t)param / 8, port = (int)(intptr_t)param % 8;
	board_t *b = &mod.boards[id];
	uint8_t *last = ddr ? &b->ddr[port] : &b->port[port];
	if (*last == (uint8_t)value)
		return 0;
	*last = (uint8_t)value;
	event(b->avr->cycle, "%s %s %c %02x", what, BOARD[id], 'A' + port, (unsigned)value & 0xFF);
	return 1;
}

static void on_port(avr_irq_t *irq, uint32_t value, void *param)
{
	(void)irq;
	if (log_register("port", 0, param, value) &&
	    (intptr_t)param == COMM * 8 + PINS_IR_MUX_PORT && ir_channel() != ir_mux_last) {
		ir_mux_last = ir_channel();
		ir_mux_at = mod.boards[COMM].avr->cycle;
	}
}

static void on_ddr(avr_irq_t *irq, uint32_t value, void *param)
{
	(void)irq;
	log_register("ddr", 1, param, value);
}

/* A Timer0 interrupt (compare match or overflow) is entered. */
static void on_timer0(avr_irq_t *irq, uint32_t value, void *param)
{
	(void)irq;
	int id = (int)(intptr_t)param;
	if (value)
		event(mod.boards[id].avr->cycle, "tick %s", BOARD[id]);
}

/* --- setup ---------------------------------------------------------------------------- */

static void board_setup(int id)
{
	char what[32], err[256];
	snprintf(what, sizeof what, "%s ELF", BOARD[id]);
	int r = module_board(&mod, id, opt.elf[id], what, opt.record[id], HEARTBEAT, err,
			     sizeof err);
	if (r)
		die(r, "%s", err);
	avr_t *avr = mod.boards[id].avr;
	for (int n = 0; n < 2; n++) {
		line_t *l = &mod.lines[id][n];
		l->overrun = on_overrun;
		if (id == COMM && n == 1)
			l->gate = ir_gate;	/* behind the IR multiplexer */
		avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0' + n),
						      UART_IRQ_OUTPUT),
					on_tx, (void *)(intptr_t)(id << 1 | n));
	}
	for (int p = 0; p < 5; p++) {
		avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('A' + p),
						      IOPORT_IRQ_REG_PORT),
					on_port, (void *)(intptr_t)(id * 8 + p));
		if (opt.trace & TRACE_DDR)
			avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('A' + p),
							      IOPORT_IRQ_DIRECTION_ALL),
						on_ddr, (void *)(intptr_t)(id * 8 + p));
	}
	if (opt.trace & TRACE_TICK) {
		static const uint8_t vectors[2] = { M162_TIMER0_COMP_VECT, M162_TIMER0_OVF_VECT };
		for (int i = 0; i < 2; i++)
			avr_irq_register_notify(avr_get_interrupt_irq(avr, vectors[i]) +
						AVR_INT_IRQ_RUNNING, on_timer0, (void *)(intptr_t)id);
	}
	if (id == CONTROL)
		module_set_dip(avr, opt.dip);
	else
		module_set_switches(avr, opt.switches);
}

/* "<sim_time_ns> <hex bytes>" lines, '#' comments; bytes go onto the line in time order. */
typedef struct { avr_cycle_count_t t; size_t at; uint8_t b; } scripted_t;

static int scripted_cmp(const void *a, const void *b)
{
	const scripted_t *x = a, *y = b;
	if (x->t != y->t)
		return x->t < y->t ? -1 : 1;
	return x->at < y->at ? -1 : x->at > y->at;
}

static void load_script(const char *path, line_t *l, unsigned baud)
{
	FILE *f = fopen(path, "r");
	if (!f)
		die(2, "cannot read script %s: %s", path, strerror(errno));
	scripted_t *s = NULL;
	size_t ns = 0, cap = 0, lineno = 0;
	char buf[8192];
	while (fgets(buf, sizeof buf, f)) {
		lineno++;
		char *p = buf, *end;
		while (*p == ' ' || *p == '\t')
			p++;
		if (*p == '#' || *p == '\n' || *p == '\r' || !*p)
			continue;
		errno = 0;
		unsigned long long ns_time = strtoull(p, &end, 10);
		if (end == p || errno || (*end != ' ' && *end != '\t'))
			die(2, "%s line %zu: expected <sim_time_ns> <hex bytes>", path, lineno);
		int hi = -1;
		for (p = end; *p && *p != '\n' && *p != '\r' && *p != '#'; p++) {
			if (*p == ' ' || *p == '\t')
				continue;
			int d = *p >= '0' && *p <= '9' ? *p - '0' :
				(*p | 0x20) >= 'a' && (*p | 0x20) <= 'f' ? (*p | 0x20) - 'a' + 10 : -1;
			if (d < 0)
				die(2, "%s line %zu: '%c' is not a hex digit", path, lineno, *p);
			if (hi < 0) {
				hi = d;
				continue;
			}
			if (ns == cap)
				s = xrealloc(s, (cap = cap ? 2 * cap : 256) * sizeof *s);
			s[ns] = (scripted_t){ ns_time / NS_PER_CYCLE, ns, (uint8_t)(hi << 4 | d) };
			ns++;
			hi = -1;
		}
		if (hi >= 0)
			die(2, "%s line %zu: odd number of hex digits", path, lineno);
	}
	fclose(f);
	qsort(s, ns, sizeof *s, scripted_cmp);
	for (size_t i = 0; i < ns; i++)
		line_push_pc(l, s[i].b, s[i].t, baud);
	free(s);
}

/* --- running ------------------------------------------------------------------------ */

static void step_until(avr_cycle_count_t target)
{
	board_t *b;
	char err[256];
	int r;
	while ((r = module_run(&mod, target, &b, err, sizeof err)) > 0)
		fprintf(stderr, "hexbot-simavr: %s board halted (SLEEP with interrupts off)"
			" at PC 0x%04x\n", BOARD[b->id], b->avr->pc);
	if (r < 0) {
		flush_events(~(avr_cycle_count_t)0);
		die(1, "%s", err);
	}
}

static uint64_t mono_ns(void)
{
	struct timespec ts;
	clock_gettime(CLOCK_MONOTONIC, &ts);
	return (uint64_t)ts.tv_sec * 1000000000ULL + ts.tv_nsec;
}

static void on_signal(int sig)
{
	(void)sig;
	stop_signal = 1;
}

/* A slice runs ahead of the wall clock: wait for it before anything of the slice shows
 * on a pty (or in the log); say so once if the simulation falls far behind. */
static void pace(pty_t *ir, pty_t *debug, avr_cycle_count_t now, uint64_t t0,
		 uint64_t *max_lag)
{
	static int warned;
	uint64_t sim = now * NS_PER_CYCLE, wall = mono_ns() - t0;
	if (wall > sim && wall - sim > *max_lag)
		*max_lag = wall - sim;
	if (sim > wall) {
		uint64_t at = t0 + sim;
		struct timespec ts = { (time_t)(at / 1000000000ULL), (long)(at % 1000000000ULL) };
		while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL) == EINTR &&
		       !stop_signal)
			;
	} else if (wall - sim > BEHIND_WARN_NS && !warned) {
		warned = 1;
		fprintf(stderr, "hexbot-simavr: warning: simulation is more than 100 ms "
			"behind the wall clock\n");
	}
	pty_flush(ir, now);
	pty_flush(debug, now);
	pty_poll(ir, now);
	pty_poll(debug, now);
}

static void usage_error(const char *fmt, const char *arg)
{
	char msg[256];
	snprintf(msg, sizeof msg, fmt, arg);
	die(2, "%s (try --help)", msg);
}

static long parse_int(const char *s, const char *what, long lo, long hi)
{
	char *end;
	errno = 0;
	long v = strtol(s, &end, 0);
	if (!*s || *end || errno || v < lo || v > hi) {
		char msg[128];
		snprintf(msg, sizeof msg, "bad %s '%%s' (%ld..%ld)", what, lo, hi);
		usage_error(msg, s);
	}
	return v;
}

static const char USAGE[] =
	"usage: hexbot-simavr --comm COMM.elf --control CONTROL.elf [--ir-link PATH]\n"
	"         [--debug-link PATH] [--dip N] [--switches MASK] [--seconds S]\n"
	"         [--fast] [--ir-script IN] [--debug-script IN] [--log OUT|-] [--verbose]\n"
	"         [--hold] [--board-record BOARD=KIND]... [--trace ddr,tick]\n";

static int board_kind(const char *s)
{
	return !strcmp(s, "comm") ? BOARD_KIND_COMM : !strcmp(s, "control") ? BOARD_KIND_CONTROL :
	       !strcmp(s, "none") ? 0 : -1;
}

/* --board-record comm=control: the comm board's EEPROM names a control board. */
static void parse_record(const char *arg)
{
	int id = !strncmp(arg, "comm=", 5) ? COMM : !strncmp(arg, "control=", 8) ? CONTROL : -1;
	int kind = id < 0 ? -1 : board_kind(strchr(arg, '=') + 1);
	if (kind < 0)
		usage_error("bad --board-record '%s' (BOARD=KIND: comm or control = comm, control "
			    "or none)", arg);
	opt.record[id] = kind;
}

/* --trace ddr,tick: DDR changes and Timer0 interrupt entries in the log as well. */
static void parse_trace(const char *arg)
{
	char buf[64];
	snprintf(buf, sizeof buf, "%s", arg);
	for (char *save, *w = strtok_r(buf, ",", &save); w; w = strtok_r(NULL, ",", &save)) {
		if (!strcmp(w, "ddr"))
			opt.trace |= TRACE_DDR;
		else if (!strcmp(w, "tick"))
			opt.trace |= TRACE_TICK;
		else
			usage_error("bad --trace '%s' (a list of ddr, tick)", arg);
	}
	if (!opt.trace)
		usage_error("bad --trace '%s' (a list of ddr, tick)", arg);
}

static void parse_args(int argc, char **argv)
{
	static const struct option longs[] = {
		{ "comm", 1, 0, 'c' }, { "control", 1, 0, 'C' }, { "ir-link", 1, 0, 'i' },
		{ "debug-link", 1, 0, 'd' }, { "dip", 1, 0, 'D' }, { "switches", 1, 0, 'w' },
		{ "seconds", 1, 0, 's' }, { "fast", 0, 0, 'f' }, { "ir-script", 1, 0, 'I' },
		{ "debug-script", 1, 0, 'S' }, { "log", 1, 0, 'l' }, { "verbose", 0, 0, 'v' },
		{ "hold", 0, 0, 'H' }, { "help", 0, 0, 'h' }, { "board-record", 1, 0, 'r' },
		{ "trace", 1, 0, 't' }, { 0, 0, 0, 0 },
	};
	int c;
	opterr = 0;
	while ((c = getopt_long(argc, argv, ":", longs, NULL)) != -1) {
		char *end;
		switch (c) {
		case 'c': opt.elf[COMM] = optarg; break;
		case 'C': opt.elf[CONTROL] = optarg; break;
		case 'i': opt.ir_link = optarg; break;
		case 'd': opt.debug_link = optarg; break;
		case 'D': opt.dip = (int)parse_int(optarg, "--dip", 0, 255); break;
		case 'w': opt.switches = (int)parse_int(optarg, "--switches", 0, 63); break;
		case 's':
			opt.seconds = strtod(optarg, &end);
			if (!*optarg || *end || !(opt.seconds > 0) || opt.seconds > 1e6)
				usage_error("bad --seconds '%s'", optarg);
			break;
		case 'f': opt.fast = 1; break;
		case 'I': opt.ir_script = optarg; break;
		case 'S': opt.debug_script = optarg; break;
		case 'l': opt.log = optarg; break;
		case 'v': opt.verbose = 1; break;
		case 'H': opt.hold = 1; break;
		case 'r': parse_record(optarg); break;
		case 't': parse_trace(optarg); break;
		case 'h': fputs(USAGE, stdout); exit(0);
		case ':': usage_error("%s needs a value", argv[optind - 1]); break;
		default: usage_error("unknown option %s", argv[optind - 1]);
		}
	}
	if (optind < argc)
		usage_error("unexpected argument '%s'", argv[optind]);
	if (!opt.elf[COMM] || !opt.elf[CONTROL])
		usage_error("%s", "--comm and --control are required");
	if (opt.fast && !(opt.seconds > 0))
		usage_error("%s", "--fast needs --seconds");
	if (opt.fast && (opt.ir_link || opt.debug_link))
		usage_error("%s", "--fast has no pseudo-terminals (no --ir-link/--debug-link)");
	if (opt.trace && !opt.log)
		usage_error("%s", "--trace needs --log");
}

int main(int argc, char **argv)
{
	parse_args(argc, argv);
	avr_global_logger_set(quiet_logger);
	signal(SIGPIPE, SIG_IGN);

	board_setup(COMM);
	board_setup(CONTROL);
	if (opt.log) {
		logfp = strcmp(opt.log, "-") ? fopen(opt.log, "w") : stdout;
		if (!logfp)
			die(2, "cannot write %s: %s", opt.log, strerror(errno));
		if (!opt.fast)
			setvbuf(logfp, NULL, _IOLBF, 0);	/* followable while it runs */
	}
	if (opt.ir_script)
		load_script(opt.ir_script, &mod.lines[COMM][1], IR_PC_BAUD);
	if (opt.debug_script)
		load_script(opt.debug_script, &mod.lines[CONTROL][1], DEBUG_PC_BAUD);

	struct sigaction sa = { .sa_handler = on_signal };
	sigemptyset(&sa.sa_mask);
	sigaction(SIGINT, &sa, NULL);
	sigaction(SIGTERM, &sa, NULL);

	if (!opt.fast) {
		ir_pty.link = opt.ir_link;
		ir_pty.in = &mod.lines[COMM][1];
		debug_pty.link = opt.debug_link;
		debug_pty.in = &mod.lines[CONTROL][1];
		pty_open(&ir_pty);
		pty_open(&debug_pty);
		printf("hexbot-simavr: ir=%s debug=%s\n", ir_pty.slave, debug_pty.slave);
		fflush(stdout);
		/* --hold: power up once a program has opened the IR pty, so it sees the boot
		 * from the first byte (the master reports POLLHUP while nobody has the slave) */
		while (opt.hold && !stop_signal) {
			struct pollfd pfd = { .fd = ir_pty.fd, .events = POLLIN };
			if (poll(&pfd, 1, 20) >= 0 && !(pfd.revents & POLLHUP))
				break;
		}
	}

	avr_cycle_count_t end = opt.seconds > 0 ? (avr_cycle_count_t)(opt.seconds * F_CPU + 0.5)
						 : ~(avr_cycle_count_t)0;
	uint64_t t0 = mono_ns(), max_lag = 0;
	/* The process that started us (in a session of its own, so a terminal's Ctrl-C does not
	 * reach us twice) may die without a word (SIGKILL): then nobody would ever stop us. */
	pid_t parent = getppid();
	unsigned long slices = 0;
	while (!stop_signal) {
		if (!opt.fast && (++slices & 255) == 0 && getppid() != parent) {
			fprintf(stderr, "hexbot-simavr: the process that started us is gone; stopping\n");
			break;
		}
		avr_cycle_count_t now = module_now(&mod);
		if (now == ~(avr_cycle_count_t)0 || now >= end)
			break;
		step_until(now + SLICE < end ? now + SLICE : end);
		now = module_now(&mod);
		if (!opt.fast)
			pace(&ir_pty, &debug_pty, now, t0, &max_lag);
		if (logfp)
			flush_events(now > 2 * HEARTBEAT ? now - 2 * HEARTBEAT : 0);
	}
	if (logfp)
		flush_events(~(avr_cycle_count_t)0);

	unsigned long overruns = 0, gated = 0, rx_off = 0;
	for (int i = 0; i < 4; i++) {
		overruns += mod.lines[i / 2][i % 2].overruns;
		gated += mod.lines[i / 2][i % 2].gated;
		rx_off += mod.lines[i / 2][i % 2].rx_off + mod.lines[i / 2][i % 2].full;
	}
	char lag[48] = "";
	if (!opt.fast)
		snprintf(lag, sizeof lag, ", most behind the wall clock %.1f ms", max_lag / 1e6);
	fprintf(stderr, "hexbot-simavr: stopped at %.6f s: IR bytes out a side %lu, IR bytes in "
		"while a side was selected %lu, UART overruns %lu, bytes lost with the receiver "
		"off %lu, pty bytes dropped %lu%s\n",
		module_now(&mod) == ~(avr_cycle_count_t)0 ? 0.0 : module_now(&mod) / (double)F_CPU,
		ir_side_out, gated, overruns, rx_off, ir_pty.lost + debug_pty.lost, lag);
	cleanup();
	return 0;
}
