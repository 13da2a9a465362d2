/* One HexBot module in simavr (module.h). */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "sim_elf.h"
#include "sim_cycle_timers.h"
#include "avr_eeprom.h"
#include "avr_ioport.h"
#include "avr_uart.h"
#include "atmega162.h"
#include "hexbot_pins.h"
#include "module.h"

const char *const BOARD[2] = { "comm", "control" };

/* 0, or 2 and one line in err for anything that is not a readable AVR ELF that fits. */
static int load_elf(board_t *b, const char *path, const char *what, char *err, size_t errlen)
{
	unsigned char h[20];
	FILE *f = fopen(path, "rb");
	if (!f) {
		snprintf(err, errlen, "cannot read %s %s: %s", what, path, strerror(errno));
		return 2;
	}
	size_t n = fread(h, 1, sizeof h, f);
	fclose(f);
	if (n < sizeof h || memcmp(h, "\177ELF", 4) || h[4] != 1 /* 32-bit */ ||
	    h[5] != 1 /* little endian */ || h[18] != 83 || h[19] != 0 /* EM_AVR */) {
		snprintf(err, errlen, "%s is not an AVR ELF (%s board)", path, BOARD[b->id]);
		return 2;
	}
	elf_firmware_t fw;
	memset(&fw, 0, sizeof fw);
	if (elf_read_firmware(path, &fw) != 0 || !fw.flashsize) {
		snprintf(err, errlen, "cannot load %s (%s board)", path, BOARD[b->id]);
		return 2;
	}
	if (fw.flashbase + fw.flashsize > FLASH_SIZE) {
		snprintf(err, errlen, "%s needs %u bytes of flash, the ATmega162 has %d", path,
			 fw.flashbase + fw.flashsize, FLASH_SIZE);
		return 2;
	}
	if (fw.mmcu[0] && strcmp(fw.mmcu, "atmega162")) {
		snprintf(err, errlen, "%s is built for %s, not atmega162", path, fw.mmcu);
		return 2;
	}
	avr_load_firmware(b->avr, &fw);
	b->avr->frequency = F_CPU;	/* the boards' crystal, whatever the ELF says */
	return 0;
}

/* The board-kind record (bus/chip.py) at the start of the EEPROM, as `hexbench firmware
 * flash --board` writes it; kind 0 leaves those bytes erased. */
static void set_board_record(avr_t *avr, int kind)
{
	uint8_t rec[4] = { 0xFF, 0xFF, 0xFF, 0xFF };
	if (kind) {
		rec[0] = BOARD_RECORD_MAGIC0;
		rec[1] = BOARD_RECORD_MAGIC1;
		rec[2] = (uint8_t)kind;
		rec[3] = (uint8_t)(kind ^ 0xFF);
	}
	avr_eeprom_desc_t d = { .ee = rec, .offset = BOARD_RECORD_ADDR, .size = sizeof rec };
	avr_ioctl(avr, AVR_IOCTL_EEPROM_SET, &d);
}

static void set_inputs(avr_t *avr, int port, uint8_t mask, uint8_t value)
{
	char name = 'A' + port;
	avr_ioport_external_t e = { .name = name, .mask = mask, .value = value };
	avr_ioctl(avr, AVR_IOCTL_IOPORT_SET_EXTERNAL(name), &e);
	for (int i = 0; i < 8; i++)
		if (mask & (1 << i))
			avr_raise_irq(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ(name), i),
				      (value >> i) & 1);
}

/* A closed switch pulls its pin to the active level; an open one leaves it to the pull-up
 * (high) or, active high, low. */
void module_set_switches(avr_t *avr, int switches)
{
	uint8_t mask[5] = { 0 }, value[5] = { 0 };
	for (int k = 1; k <= 6; k++) {
		int closed = (switches >> (k - 1)) & 1;
		mask[PINS_SWITCH_PORTS[k]] |= PINS_SWITCH_MASKS[k];
		if (closed != PINS_SWITCH_ACTIVE_LOW)
			value[PINS_SWITCH_PORTS[k]] |= PINS_SWITCH_MASKS[k];
	}
	for (int p = 0; p < 5; p++)
		if (mask[p])
			set_inputs(avr, p, mask[p], value[p]);
}

void module_set_dip(avr_t *avr, int dip)
{
	set_inputs(avr, PINS_DIP_PORT, 0xFF, (uint8_t)(PINS_DIP_ACTIVE_LOW ? ~dip : dip));
}

/* A heartbeat timer bounds how far SLEEP jumps (param: its period in cycles). */
static avr_cycle_count_t heartbeat(avr_t *avr, avr_cycle_count_t when, void *param)
{
	(void)avr;
	return when + (avr_cycle_count_t)(uintptr_t)param;
}

int module_board(module_t *m, int id, const char *elf, const char *what, int record,
		 avr_cycle_count_t beat, char *err, size_t errlen)
{
	board_t *b = &m->boards[id];
	b->id = id;
	b->avr = atmega162_new();
	if (!b->avr) {
		snprintf(err, errlen, "out of memory");
		return 1;
	}
	int r = load_elf(b, elf, what, err, errlen);
	if (r)
		return r;
	set_board_record(b->avr, record);
	for (int n = 0; n < 2; n++)
		line_attach(&m->lines[id][n], b->avr, id, n);
	avr_cycle_timer_register(b->avr, beat, heartbeat, (void *)(uintptr_t)beat);
	return 0;
}

avr_cycle_count_t module_tx(module_t *m, int id, int n, uint8_t b, avr_cycle_count_t *frame)
{
	avr_t *avr = m->boards[id].avr;
	avr_cycle_count_t now = avr->cycle, len = atmega162_uart_frame_cycles(avr, n);
	avr_cycle_count_t start = now > m->tx_busy[id][n] ? now : m->tx_busy[id][n];
	m->tx_busy[id][n] = start + len;
	if (n == 0)
		line_push(&m->lines[!id][0], b, start, len, atmega162_uart_bit_cycles(avr, 0));
	*frame = len;
	return start;
}

int module_run(module_t *m, avr_cycle_count_t until, board_t **who, char *err, size_t errlen)
{
	for (;;) {
		board_t *b = NULL;
		for (int i = 0; i < 2; i++)
			if (!m->boards[i].halted &&
			    (!b || m->boards[i].avr->cycle < b->avr->cycle))
				b = &m->boards[i];
		if (!b || b->avr->cycle >= until)
			return 0;
		*who = b;
		avr_flashaddr_t pc = b->avr->pc;	/* the instruction this step executes */
		int state = avr_run(b->avr);
		if (state == cpu_Done) {
			b->halted = 1;
			return 1;
		}
		if (state == cpu_Crashed || state == cpu_Stopped) {
			b->halted = 1;
			snprintf(err, errlen, "%s board crashed at PC 0x%04x (byte address) after %.6f s",
				 BOARD[b->id], pc, b->avr->cycle / (double)F_CPU);
			return -1;
		}
	}
}

avr_cycle_count_t module_now(const module_t *m)
{
	avr_cycle_count_t t = ~(avr_cycle_count_t)0;
	for (int i = 0; i < 2; i++)
		if (!m->boards[i].halted && m->boards[i].avr->cycle < t)
			t = m->boards[i].avr->cycle;
	return t;
}

void module_free(module_t *m)
{
	for (int id = 0; id < 2; id++) {
		if (m->boards[id].avr) {
			avr_terminate(m->boards[id].avr);
			free(m->boards[id].avr);
			m->boards[id].avr = NULL;
		}
		for (int n = 0; n < 2; n++)
			line_free(&m->lines[id][n]);
	}
}
