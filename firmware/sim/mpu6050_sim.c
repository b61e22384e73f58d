/* mpu6050_sim: the bridge firmware's ELF on a simulated ATmega328P (libsimavr), with
 *   - UART0 on a pseudo-terminal (raw mode) that pyserial opens like /dev/ttyUSB0;
 *   - an MPU6050 register model at I2C address 0x68 on the TWI bus
 *     (RM-MPU-6000A-00 rev 4.2: WHO_AM_I, PWR_MGMT_1, SMPLRT_DIV, CONFIG, ACCEL_CONFIG,
 *     INT_ENABLE, INT_STATUS, ACCEL_XOUT_H..TEMP_OUT_L at 0x3B, XA/YA/ZA_OFFS at 0x06) that
 *     samples on its own clock: the chip's clock runs PPM parts per million fast (negative: slow)
 *     against the MCU's, a new sample lands in the data registers every sample period of chip
 *     time whether or not anyone reads them, and INT_STATUS.DATA_RDY_INT (with INT_ENABLE's
 *     DATA_RDY_EN) is set by a new sample and cleared by reading INT_STATUS, as the real part;
 *   - the AVR's own 1 KiB EEPROM (simavr's model), the NVM the firmware pages;
 *   - stack painting: free RAM between the static data and the deepest stack.
 *
 * Usage: mpu6050_sim FIRMWARE.elf [-o XOFF,YOFF,ZOFF] [-w WHO_AM_I] [-p PPM] [-t XA,YA,ZA] [-r RX,RY,RZ] [-s STEP] [-H CLOCKS]
 *   -s: XA/YA/ZA_OFFS step as a share of 1/2048 g (1: the application note's +-16 g format; a fault:
 *       a part whose offset-register unit differs from what the host driver assumes).
 *   -t: the accelerometer's factory self-test codes XA_TEST..ZA_TEST (5 bits each, in SELF_TEST_X/Y/Z/A);
 *   -r: the chip's self-test response per axis as a share of its factory trim FT (1: exactly FT;
 *       0: a self-test that does nothing).  FT = 4096 * 0.34 * (0.92 / 0.34)^((code - 1) / 30) LSB at
 *       +-8 g (register map rev 4.2, 4.1), applied while ACCEL_CONFIG's XA/YA/ZA_ST bits are set.
 *
 * Side channel: stdin / stdout, one text line per message (the Python side owns both).
 *   stdout "PTY <path>"              once, when the port is ready
 *   stdout "CFG <accel_config> <config> <smplrt_div> <pwr_mgmt_1>"  after the firmware writes one
 *   stdout "NEED <k>"                the data registers are read, k chip samples were made since the
 *                                    last one fetched and no sample is queued: the simulation waits
 *                                    (simulated time stands still) for a "D" (the newest of the k;
 *                                    the side channel advances its board by k samples)
 *   stdout "STATS <key>=<value> ..." in answer to "S"
 *   stdin  "D <x> <y> <z> <temp>"    one sample: accelerometer counts at the configured range with
 *                                    the factory trim (int16) and TEMP_OUT (int16); queued, one per
 *                                    new chip sample that is read
 *   stdin  "X"                       drop queued samples (the board was moved)
 *   stdin  "A 0" / "A 1"             the MPU6050 leaves / rejoins the bus (no ACK to its address)
 *   stdin  "E <addr> <value>"        EEPROM cell <addr> is worn: it always reads <value>
 *   stdin  "E -1"                    no worn cell
 *   stdin  "B <k>"                   reset the MCU (external reset) after k more samples; "B 0": now
 *   stdin  "S"                       report statistics
 *   stdin  "Q"                       quit
 * The simulation runs as fast as the host CPU allows; it never sleeps.  Simulated time is the
 * firmware's time (its timer0, its UART bit timing at 115200 baud).
 */
#define _GNU_SOURCE
#include <errno.h>
#include <math.h>
#include <fcntl.h>
#include <poll.h>
#include <pty.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <unistd.h>

#include "avr_eeprom.h"
#include "avr_ioport.h"
#include "avr_twi.h"
#include "avr_uart.h"
#include "sim_avr.h"
#include "sim_elf.h"
#include "sim_io.h"
#include "sim_irq.h"

#define MPU_ADDR 0x68
#define REG_XA_OFFS_H 0x06
#define REG_SELF_TEST_X 0x0D
#define REG_SELF_TEST_A 0x10
#define REG_SMPLRT_DIV 0x19
#define REG_CONFIG 0x1A
#define REG_ACCEL_CONFIG 0x1C
#define REG_INT_ENABLE 0x38
#define REG_INT_STATUS 0x3A
#define DATA_RDY 0x01
#define REG_ACCEL_XOUT_H 0x3B
#define REG_TEMP_OUT_H 0x41
#define REG_PWR_MGMT_1 0x6B
#define REG_WHO_AM_I 0x75
#define PWR_SLEEP 0x40
#define PWR_DEVICE_RESET 0x80
#define OFFSET_LSB_PER_G 2048  /* XA/YA/ZA_OFFS: +-16 g format (InvenSense offset-register app note) */
static double offset_step_scale = 1.0;  /* -s: the part's step as a share of 1/2048 g */
#define PAINT 0xA5
#define QUEUE_LEN 4096
#define OUT_LEN (1 << 20)

static avr_t *avr;
static int pty_master = -1;

/* --- MPU6050 register model ---------------------------------------------------------- */
typedef struct { int16_t v[4]; } sample_t;  /* x, y, z counts, TEMP_OUT */

static struct {
  uint8_t regs[0x80];
  int16_t factory[3];
  int st_code[3];      /* factory self-test codes (5 bits) */
  double st_share[3];  /* this chip's self-test response / FT */
  uint8_t who;
  int absent;  /* 1: nothing answers at 0x68 (unplugged breakout) */
  avr_irq_t *irq;
  uint8_t selected, index, reg;
  sample_t queue[QUEUE_LEN];
  unsigned head, tail;
  unsigned long samples_used, waits, i2c_bytes;
  /* the chip's own clock: sample k lands at chip time epoch_us + (k - epoch_k) * period */
  double ppm, epoch_us;
  unsigned long long epoch_k, latched_k, status_k;
  int burst;                 /* 1: the next byte read is the first of this transaction */
  int burst_data;            /* 1: this transaction has read the data registers */
  unsigned long long burst_k;  /* the chip's newest sample when this transaction's reads began */
  unsigned long data_reads;  /* burst reads that included the data registers */
} mpu;

static void put_be16(uint8_t *p, int v) { p[0] = (uint8_t)((v >> 8) & 0xFF); p[1] = (uint8_t)(v & 0xFF); }
static int get_be16(const uint8_t *p) { return (int16_t)((p[0] << 8) | p[1]); }

static void mpu_power_on_reset(void) {
  memset(mpu.regs, 0, sizeof(mpu.regs));
  mpu.regs[REG_WHO_AM_I] = mpu.who;
  mpu.regs[REG_PWR_MGMT_1] = PWR_SLEEP;
  for (int i = 0; i < 3; i++) put_be16(mpu.regs + REG_XA_OFFS_H + 2 * i, mpu.factory[i]);
  /* SELF_TEST_X/Y/Z bits 7:5 = A_TEST[4:2]; SELF_TEST_A bits 5:4, 3:2, 1:0 = X/Y/Z A_TEST[1:0] */
  mpu.regs[REG_SELF_TEST_A] = 0;
  for (int i = 0; i < 3; i++) {
    mpu.regs[REG_SELF_TEST_X + i] = (uint8_t)(((mpu.st_code[i] >> 2) & 7) << 5);
    mpu.regs[REG_SELF_TEST_A] |= (uint8_t)((mpu.st_code[i] & 3) << (4 - 2 * i));
  }
}

/* The self-test force on an axis, in g: FT / 4096 LSB per g at +-8 g, times this chip's share. */
static double self_test_g(int axis) {
  int c = mpu.st_code[axis];
  double ft = c ? 4096.0 * 0.34 * pow(0.92 / 0.34, (c - 1) / 30.0) : 0.0;
  return ft / 4096.0 * mpu.st_share[axis];
}

static void side_input(int block);
static long reset_after = -1;  /* samples until an external reset; -1: none */
static int reset_now;

/* The chip's time in us: the MCU's cycles at 16 MHz, the chip's oscillator PPM off. */
static double chip_us(void) { return (double)avr->cycle / 16.0 * (1.0 + mpu.ppm * 1e-6); }

/* Sample period in chip us: gyro rate (8 kHz with DLPF_CFG 0, else 1 kHz) / (1 + SMPLRT_DIV);
 * the accelerometer itself samples at 1 kHz, so never shorter than 1000 us. */
static double period_us(void) {
  double p = ((mpu.regs[REG_CONFIG] & 7) == 0 ? 125.0 : 1000.0) * (1 + mpu.regs[REG_SMPLRT_DIV]);
  return p < 1000.0 ? 1000.0 : p;
}

/* Index of the newest sample the chip has made (asleep: none since it fell asleep). */
static unsigned long long chip_k(void) {
  if (mpu.regs[REG_PWR_MGMT_1] & PWR_SLEEP) return mpu.epoch_k;
  double dt = chip_us() - mpu.epoch_us;
  return mpu.epoch_k + (dt > 0 ? (unsigned long long)(dt / period_us()) : 0);
}

/* A rate or power change: samples from now on are counted at the new period. */
static void chip_new_epoch(void) {
  mpu.epoch_k = chip_k();
  mpu.epoch_us = chip_us();
}

static void mpu_new_sample(unsigned long long made);

/* A read of the data registers: they hold the chip's newest sample, fetched when there is one. */
static void mpu_data_read(unsigned long long k) {
  mpu.data_reads++;
  if (k > mpu.latched_k) {
    mpu_new_sample(k - mpu.latched_k);  /* samples_used counts the distinct samples ever read */
    mpu.latched_k = k;
  }
}

/* INT_STATUS on read: DATA_RDY_INT set by every new sample since the last read, cleared by this read. */
static uint8_t mpu_int_status(unsigned long long k) {
  uint8_t v = (mpu.regs[REG_INT_ENABLE] & DATA_RDY) && k > mpu.status_k ? DATA_RDY : 0;
  mpu.status_k = k;
  return v;
}

/* One sample into the data registers: counts plus the offset registers' change from the
 * factory trim (2048 LSB per g, bit 0 reserved), scaled to the configured range. */
static void mpu_new_sample(unsigned long long made) {
  if (mpu.regs[REG_PWR_MGMT_1] & PWR_SLEEP) return;  /* asleep: data registers hold */
  while (mpu.head == mpu.tail) {
    mpu.waits++;
    printf("NEED %llu\n", made);
    fflush(stdout);
    side_input(1);
  }
  sample_t s = mpu.queue[mpu.tail++ % QUEUE_LEN];
  mpu.samples_used++;
  if (reset_after > 0 && --reset_after == 0) reset_now = 1;
  int afs = (mpu.regs[REG_ACCEL_CONFIG] >> 3) & 3;
  for (int i = 0; i < 3; i++) {
    int d = (get_be16(mpu.regs + REG_XA_OFFS_H + 2 * i) & ~1) - (mpu.factory[i] & ~1);
    long v = s.v[i] + lround((double)d * (16384 >> afs) / OFFSET_LSB_PER_G * offset_step_scale);
    if (mpu.regs[REG_ACCEL_CONFIG] & (0x80 >> i)) v += lround(self_test_g(i) * (16384 >> afs));
    v = v < -32768 ? -32768 : v > 32767 ? 32767 : v;
    put_be16(mpu.regs + REG_ACCEL_XOUT_H + 2 * i, (int)v);
  }
  put_be16(mpu.regs + REG_TEMP_OUT_H, s.v[3]);
}

static void mpu_write(uint8_t reg, uint8_t v) {
  reg &= 0x7F;
  if (reg == REG_SMPLRT_DIV || reg == REG_CONFIG || reg == REG_PWR_MGMT_1) chip_new_epoch();
  if (reg == REG_PWR_MGMT_1 && (v & PWR_DEVICE_RESET)) {
    uint8_t keep[14];
    memcpy(keep, mpu.regs + REG_ACCEL_XOUT_H, 14);
    mpu_power_on_reset();
    memcpy(mpu.regs + REG_ACCEL_XOUT_H, keep, 14);
  } else if (reg != REG_WHO_AM_I && reg != REG_INT_STATUS && !(reg >= REG_ACCEL_XOUT_H && reg < REG_ACCEL_XOUT_H + 14)) {
    mpu.regs[reg] = v;
  }
  if (reg == REG_PWR_MGMT_1) { mpu.epoch_us = chip_us(); mpu.latched_k = mpu.status_k = mpu.epoch_k; }
  if (reg == REG_SMPLRT_DIV || reg == REG_CONFIG || reg == REG_ACCEL_CONFIG || reg == REG_PWR_MGMT_1) {
    printf("CFG %u %u %u %u\n", mpu.regs[REG_ACCEL_CONFIG], mpu.regs[REG_CONFIG], mpu.regs[REG_SMPLRT_DIV],
           mpu.regs[REG_PWR_MGMT_1]);
    fflush(stdout);
  }
}

/* TWI messages from the AVR's master (as simavr's parts/i2c_eeprom.c): START+ADDR selects,
 * the first written byte is the register pointer, later bytes are written with auto-increment;
 * reads return the register at the pointer and increment it. */
static void mpu_twi_hook(avr_irq_t *irq, uint32_t value, void *param) {
  (void)irq;
  (void)param;
  avr_twi_msg_irq_t v;
  v.u.v = value;
  if (v.u.twi.msg & TWI_COND_STOP) mpu.selected = 0;
  if (v.u.twi.msg & TWI_COND_START) {
    mpu.selected = 0;
    mpu.index = 0;
    mpu.burst = 1;
    mpu.burst_data = 0;
    if ((v.u.twi.addr >> 1) == MPU_ADDR && !mpu.absent) {
      mpu.selected = v.u.twi.addr;
      avr_raise_irq(mpu.irq + TWI_IRQ_INPUT, avr_twi_irq_msg(TWI_COND_ACK, mpu.selected, 1));
    }
  }
  if (!mpu.selected) return;
  if (v.u.twi.msg & TWI_COND_WRITE) {
    avr_raise_irq(mpu.irq + TWI_IRQ_INPUT, avr_twi_irq_msg(TWI_COND_ACK, mpu.selected, 1));
    if (mpu.index++ == 0) {
      mpu.reg = v.u.twi.data & 0x7F;
    } else {
      mpu_write(mpu.reg, v.u.twi.data);
      mpu.reg = (mpu.reg + 1) & 0x7F;
    }
    mpu.i2c_bytes++;
  }
  if (v.u.twi.msg & TWI_COND_READ) {
    /* the chip holds its registers still during a burst: status and data are of the sample
     * that was newest when the burst began */
    if (mpu.burst) mpu.burst_k = chip_k();
    mpu.burst = 0;
    if (!mpu.burst_data && mpu.reg >= REG_ACCEL_XOUT_H && mpu.reg <= REG_TEMP_OUT_H + 1) {
      mpu.burst_data = 1;
      mpu_data_read(mpu.burst_k);
    }
    uint8_t out = mpu.reg == REG_INT_STATUS ? mpu_int_status(mpu.burst_k) : mpu.regs[mpu.reg];
    avr_raise_irq(mpu.irq + TWI_IRQ_INPUT, avr_twi_irq_msg(TWI_COND_READ, mpu.selected, out));
    mpu.reg = (mpu.reg + 1) & 0x7F;
    mpu.i2c_bytes++;
  }
}

static void mpu_attach(void) {
  static const char *names[2] = {[TWI_IRQ_INPUT] = "8>mpu6050.out", [TWI_IRQ_OUTPUT] = "32<mpu6050.in"};
  mpu.irq = avr_alloc_irq(&avr->irq_pool, 0, 2, names);
  avr_irq_register_notify(mpu.irq + TWI_IRQ_OUTPUT, mpu_twi_hook, NULL);
  avr_connect_irq(mpu.irq + TWI_IRQ_INPUT, avr_io_getirq(avr, AVR_IOCTL_TWI_GETIRQ(0), TWI_IRQ_INPUT));
  avr_connect_irq(avr_io_getirq(avr, AVR_IOCTL_TWI_GETIRQ(0), TWI_IRQ_OUTPUT), mpu.irq + TWI_IRQ_OUTPUT);
}

/* --- the I2C pins before the TWI takes them: a slave holding SDA low (bus clear) ---------
 * -H N: at power-on the MPU-6050 holds SDA low (left mid-byte by a reset) until it has seen N SCL clocks
 * (rising edges), then releases it.  The lines are open drain with the bus's pull-ups: a line is low when
 * the MCU drives it (DDR 1, PORT 0) or the slave holds it.  Counted: SCL clocks, STOPs (SDA rising while
 * SCL is high), as the STATS line reports them with PORTC's SDA/SCL bits (the internal pull-ups). */
static int sda_hold_clocks, sda_held, scl_clocks, bus_stops;
static uint8_t ddrc_last;
static avr_irq_t *sda_pin, *scl_pin;

static void pins_update(uint8_t ddr) {
  int scl_low = (ddr >> 5) & 1, sda_low = ((ddr >> 4) & 1) || sda_held;
  int scl_was_low = (ddrc_last >> 5) & 1, sda_was_low = ((ddrc_last >> 4) & 1) || sda_held;
  if (scl_was_low && !scl_low) {
    scl_clocks++;
    if (sda_held && scl_clocks >= sda_hold_clocks) sda_held = 0, sda_low = (ddr >> 4) & 1;
  }
  if (!scl_low && sda_was_low && !sda_low && !scl_was_low) bus_stops++;
  ddrc_last = ddr;
  avr_raise_irq(scl_pin, !scl_low);
  avr_raise_irq(sda_pin, !sda_low);
}

static void ddrc_hook(avr_irq_t *irq, uint32_t value, void *param) {
  (void)irq;
  (void)param;
  pins_update((uint8_t)value);
}

static void pins_attach(void) {
  sda_pin = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('C'), 4);
  scl_pin = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('C'), 5);
  avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('C'), IOPORT_IRQ_DIRECTION_ALL), ddrc_hook, NULL);
  sda_held = sda_hold_clocks > 0;
  pins_update(0);
}

/* --- UART0 <-> pseudo-terminal ------------------------------------------------------- */
static uint8_t out_buf[OUT_LEN];
static size_t out_len;
static unsigned long uart_tx_bytes, uart_rx_bytes, uart_tx_lost;
static int uart_xoff;
static uint8_t in_buf[4096];
static size_t in_len, in_pos;

static void uart_out_hook(avr_irq_t *irq, uint32_t value, void *param) {
  (void)irq;
  (void)param;
  uart_tx_bytes++;
  if (out_len < OUT_LEN) out_buf[out_len++] = (uint8_t)value;
  else uart_tx_lost++;  /* host not reading: a USB-serial adapter would drop them too */
}
static void uart_xon_hook(avr_irq_t *irq, uint32_t value, void *param) { (void)irq; (void)value; (void)param; uart_xoff = 0; }
static void uart_xoff_hook(avr_irq_t *irq, uint32_t value, void *param) { (void)irq; (void)value; (void)param; uart_xoff = 1; }

static void uart_attach(void) {
  uint32_t flags = 0;
  avr_ioctl(avr, AVR_IOCTL_UART_GET_FLAGS('0'), &flags);
  flags &= ~(AVR_UART_FLAG_STDIO | AVR_UART_FLAG_POLL_SLEEP);  /* no console echo, never usleep */
  avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);
  avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT), uart_out_hook, NULL);
  avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XON), uart_xon_hook, NULL);
  avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XOFF), uart_xoff_hook, NULL);
}

static void pty_open(void) {
  int slave;
  char name[256];
  struct termios t;
  if (openpty(&pty_master, &slave, name, NULL, NULL) < 0) {
    perror("openpty");
    exit(1);
  }
  tcgetattr(slave, &t);
  cfmakeraw(&t);
  tcsetattr(slave, TCSANOW, &t);
  fcntl(pty_master, F_SETFL, O_NONBLOCK);
  /* the slave stays open here so the master never reads EIO between host sessions */
  printf("PTY %s\n", name);
  fflush(stdout);
}

static void uart_pump(void) {
  if (out_len) {
    ssize_t k = write(pty_master, out_buf, out_len);
    if (k > 0) {
      memmove(out_buf, out_buf + k, out_len - (size_t)k);
      out_len -= (size_t)k;
    }
  }
  if (in_pos == in_len) {
    ssize_t k = read(pty_master, in_buf, sizeof(in_buf));
    in_pos = 0;
    in_len = k > 0 ? (size_t)k : 0;
  }
  avr_irq_t *rx = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
  while (in_pos < in_len && !uart_xoff) {
    avr_raise_irq(rx, in_buf[in_pos++]);
    uart_rx_bytes++;
  }
}

/* --- stack painting ------------------------------------------------------------------ */
static uint16_t paint_lo;                /* first byte above .data + .bss + .noinit */
static unsigned long min_free = 0xFFFF;  /* over all boots so far */
static unsigned min_sp = 0xFFFF;         /* lowest stack pointer seen between instructions */

static void paint(void) {
  for (unsigned a = paint_lo; a <= avr->ramend; a++) avr->data[a] = PAINT;
}

static unsigned long free_now(void) {
  unsigned a = paint_lo;
  while (a <= avr->ramend && avr->data[a] == PAINT) a++;
  return a - paint_lo;
}

/* --- side channel -------------------------------------------------------------------- */
static char line[256];
static size_t line_len;
static int worn_addr = -1, worn_value;

static void side_line(const char *s) {
  int x, y, z, t;
  switch (s[0]) {
    case 'D':
      if (sscanf(s + 1, "%d %d %d %d", &x, &y, &z, &t) == 4 && mpu.head - mpu.tail < QUEUE_LEN) {
        sample_t v = {{(int16_t)x, (int16_t)y, (int16_t)z, (int16_t)t}};
        mpu.queue[mpu.head++ % QUEUE_LEN] = v;
      }
      break;
    case 'X': mpu.tail = mpu.head; break;
    case 'A':
      if (sscanf(s + 1, "%d", &x) == 1) mpu.absent = !x;
      break;
    case 'B':
      if (sscanf(s + 1, "%d", &x) == 1) {
        reset_after = x > 0 ? x : -1;
        reset_now = x <= 0;
      }
      break;
    case 'E':
      if (sscanf(s + 1, "%d %d", &x, &y) >= 1) worn_addr = x, worn_value = y;
      break;
    case 'S': {
      unsigned long f = free_now();
      printf("STATS cycles=%llu sim_us=%llu free_ram_now=%lu free_ram_min=%lu static_ram=%u ramend=%u "
             "min_sp_free=%u uart_tx=%lu uart_rx=%lu uart_lost=%lu samples=%lu waits=%lu i2c_bytes=%lu "
             "chip_samples=%llu data_reads=%lu scl_clocks=%d bus_stops=%d sda_held=%d portc_sda_scl=%d\n",
             (unsigned long long)avr->cycle, (unsigned long long)(avr->cycle / (avr->frequency / 1000000)),
             f, f < min_free ? f : min_free, paint_lo - 0x100, avr->ramend, min_sp + 1 - paint_lo, uart_tx_bytes, uart_rx_bytes,
             uart_tx_lost, mpu.samples_used, mpu.waits, mpu.i2c_bytes, chip_k(), mpu.data_reads, scl_clocks, bus_stops,
             sda_held, (avr->data[0x28] >> 4) & 3);  /* PORTC (data address 0x28): bits 4 SDA, 5 SCL */
      fflush(stdout);
      break;
    }
    case 'Q': exit(0);
  }
}

/* Read what stdin has; with block, wait until at least one whole line was handled. */
static void side_input(int block) {
  for (;;) {
    struct pollfd p = {0, POLLIN, 0};
    int handled = 0;
    if (poll(&p, 1, block ? 50 : 0) > 0) {
      char buf[4096];
      ssize_t k = read(0, buf, sizeof(buf));
      if (k <= 0) exit(0);  /* the Python side went away */
      for (ssize_t i = 0; i < k; i++) {
        if (buf[i] == '\n') {
          line[line_len] = 0;
          side_line(line);
          line_len = 0;
          handled = 1;
        } else if (line_len < sizeof(line) - 1) {
          line[line_len++] = buf[i];
        }
      }
    } else if (block) {
      uart_pump();  /* keep the host link moving while waiting */
    }
    if (!block || (handled && mpu.head != mpu.tail)) return;
  }
}

static void worn_cell(void) {
  avr_eeprom_desc_t d = {.ee = NULL, .offset = (uint16_t)worn_addr, .size = 1};
  uint8_t b = 0;
  d.ee = &b;
  avr_ioctl(avr, AVR_IOCTL_EEPROM_GET, &d);
  if (b != (uint8_t)worn_value) {
    b = (uint8_t)worn_value;
    d.ee = &b;
    avr_ioctl(avr, AVR_IOCTL_EEPROM_SET, &d);
  }
}

int main(int argc, char **argv) {
  elf_firmware_t fw;
  int opt, ox = 1001, oy = -2000, oz = 3, who = 0x68;
  double ppm = 0.0;
  mpu.st_code[0] = 14, mpu.st_code[1] = 15, mpu.st_code[2] = 13;
  mpu.st_share[0] = mpu.st_share[1] = mpu.st_share[2] = 1.0;
  while ((opt = getopt(argc, argv, "o:w:p:t:r:s:H:")) != -1) {
    if (opt == 't' && sscanf(optarg, "%d,%d,%d", &mpu.st_code[0], &mpu.st_code[1], &mpu.st_code[2]) == 3) {
      for (int i = 0; i < 3; i++) mpu.st_code[i] &= 31;
      continue;
    }
    if (opt == 'r' && sscanf(optarg, "%lf,%lf,%lf", &mpu.st_share[0], &mpu.st_share[1], &mpu.st_share[2]) == 3) continue;
    if (opt == 's' && sscanf(optarg, "%lf", &offset_step_scale) == 1 && offset_step_scale > 0 && offset_step_scale < 10) continue;
    if (opt == 'o' && sscanf(optarg, "%d,%d,%d", &ox, &oy, &oz) == 3) continue;
    if (opt == 'w' && sscanf(optarg, "%i", &who) == 1) continue;
    if (opt == 'H' && sscanf(optarg, "%d", &sda_hold_clocks) == 1 && sda_hold_clocks >= 0 && sda_hold_clocks <= 64) continue;
    if (opt == 'p' && sscanf(optarg, "%lf", &ppm) == 1 && ppm > -1e5 && ppm < 1e5) continue;
    fprintf(stderr, "usage: %s FIRMWARE.elf [-o XOFF,YOFF,ZOFF] [-w WHO_AM_I] [-p PPM] [-t XA,YA,ZA] [-r RX,RY,RZ] [-s STEP] [-H CLOCKS]\n", argv[0]);
    return 2;
  }
  if (optind >= argc) {
    fprintf(stderr, "usage: %s FIRMWARE.elf [-o XOFF,YOFF,ZOFF] [-w WHO_AM_I] [-p PPM] [-t XA,YA,ZA] [-r RX,RY,RZ] [-s STEP] [-H CLOCKS]\n", argv[0]);
    return 2;
  }
  mpu.ppm = ppm;
  memset(&fw, 0, sizeof(fw));
  if (elf_read_firmware(argv[optind], &fw) != 0) {
    fprintf(stderr, "%s: cannot read ELF\n", argv[optind]);
    return 1;
  }
  avr = avr_make_mcu_by_name("atmega328p");
  if (!avr) return 1;
  avr_init(avr);
  avr->frequency = 16000000;
  avr->log = 1;  /* errors only */
  avr_load_firmware(avr, &fw);
  mpu.factory[0] = (int16_t)ox, mpu.factory[1] = (int16_t)oy, mpu.factory[2] = (int16_t)oz;
  mpu.who = (uint8_t)who;
  mpu_power_on_reset();
  mpu_attach();
  uart_attach();
  pins_attach();
  paint_lo = (uint16_t)(0x100 + fw.datasize + fw.bsssize + 3);  /* + .noinit: mcusr_at_boot, reset_magic */
  paint();
  pty_open();
  for (unsigned long n = 0;; n++) {
    if (reset_now) {
      reset_now = 0;
      reset_after = -1;
      avr_reset(avr);
      avr->data[0x54] |= 1 << 1;  /* MCUSR.EXTRF: the reset pin */
    }
    if (avr->pc == 0 && n) {  /* watchdog reset: RAM keeps its contents, the stack starts again */
      unsigned long f = free_now();
      if (f < min_free) min_free = f;
      paint();
    }
    int state = avr_run(avr);
    if (state == cpu_Done || state == cpu_Crashed) {
      fprintf(stderr, "simulated MCU stopped (state %d) at pc 0x%04x\n", state, avr->pc);
      return 3;
    }
    unsigned sp = avr->data[R_SPL] | (avr->data[R_SPH] << 8);
    if (sp < min_sp && sp >= paint_lo) min_sp = sp;
    if (worn_addr >= 0) worn_cell();
    if ((n & 1023) == 0) {
      uart_pump();
      side_input(0);
    }
  }
}
