// mpu6050_bridge.ino: serial bridge between the accelcal host and an MPU6050 on I2C.
//
// Board: Arduino Uno / Nano / Pro Mini (ATmega328P, 5 V or 3.3 V) or any AVR
// Arduino with Wire and EEPROM.  Wiring: SDA (A4 on Uno/Nano) and SCL (A5) to the
// MPU6050 breakout's SDA/SCL, VCC to 3.3 V (or 5 V only if the breakout has its own
// regulator and level shifting), GND to GND, AD0 to GND for I2C address 0x68
// (AD0 high gives 0x69: change MPU_ADDR).
//
// Protocol: docs/bridge-protocol.md.  The #define block between BEGIN PROTOCOL and
// END PROTOCOL must equal the constants in drivers/bridge_protocol.py; the host
// test suite (tests/test_bridge_protocol.py) parses this file and checks it, and
// checks TEST_FRAME / TEST_FRAME_CRC against the host CRC.
//
// Build: Arduino IDE, `arduino-cli compile --fqbn arduino:avr:uno firmware/mpu6050_bridge`, or
// `make -C firmware` (Debian gcc-avr + arduino-mk; also builds the simavr harness in firmware/sim).

#include <Arduino.h>
#include <Wire.h>
#include <EEPROM.h>
#include <avr/wdt.h>

// BEGIN PROTOCOL
#define PROTOCOL_VERSION 1
#define DEFAULT_BAUD 115200
#define SYNC0 0xA5
#define SYNC1 0x5A
#define HEADER_LEN 8          // LEN(1) SEQ(2) TYPE(1) TS(4), little-endian
#define MAX_PAYLOAD 64
#define CRC16_POLY 0x1021     // CRC-16/CCITT-FALSE over LEN..PAYLOAD
#define CRC16_INIT 0xFFFF
#define CRC16_XOROUT 0x0000
#define CRC16_CHECK 0x29B1    // CRC of "123456789"

#define CMD_IDENTIFY 0x01
#define CMD_CONFIGURE 0x02
#define CMD_STREAM 0x03
#define CMD_STOP 0x04
#define CMD_READ_REG 0x05
#define CMD_WRITE_REG 0x06
#define CMD_NVM_READ 0x07
#define CMD_NVM_WRITE 0x08
#define CMD_RESET 0x09
#define CMD_SELF_TEST 0x0A

#define RSP_BOOT 0x80
#define RSP_ACK 0x81
#define RSP_NAK 0x82
#define RSP_SAMPLE 0x83
#define RSP_STREAM_END 0x84

#define ERR_UNKNOWN_CMD 0x01
#define ERR_BAD_LENGTH 0x02
#define ERR_BAD_ARG 0x03
#define ERR_I2C 0x04
#define ERR_NVM 0x05

#define BOOT_POWER_ON 0x00
#define BOOT_COMMAND 0x01
#define BOOT_WATCHDOG 0x02
#define BOOT_EXTERNAL 0x03

#define NVM_SIZE 1024
#define NVM_PAGE_SIZE 32
#define REG_MAX_COUNT 16
#define SAMPLE_BYTES 8        // ACCEL_XOUT_H (0x3B) .. TEMP_OUT_L (0x42), big-endian
#define SELF_TEST_MAX_N 1024  // samples averaged per SELF_TEST phase
#define SELF_TEST_SETTLE_MS 200
// END PROTOCOL

// Known-answer test: a SAMPLE frame (seq 0x0102, ts 12345678 us, index 7,
// x=16 y=-16 z=16384 counts, TEMP_OUT=-3528).  setup() checks crc16() against
// TEST_FRAME_CRC; the host test checks the same bytes with its own CRC.
static const uint8_t TEST_FRAME[] = {
  0xA5, 0x5A, 0x0C, 0x02, 0x01, 0x83, 0x4E, 0x61, 0xBC, 0x00, 0x07, 0x00,
  0x00, 0x00, 0x00, 0x10, 0xFF, 0xF0, 0x40, 0x00, 0xF2, 0x38, 0x0F, 0xA6};
#define TEST_FRAME_CRC 0xA60F

// Board settings
#define FW_VERSION_MAJOR 1
#define FW_VERSION_MINOR 1
#define MPU_ADDR 0x68               // AD0 low; 0x69 with AD0 high
#define BRIDGE_SERIAL "MPUB0001"    // 8 characters, set per board before flashing
#define I2C_CLOCK_HZ 400000UL
#define I2C_TIMEOUT_US 25000UL
#define RESET_MAGIC 0xB007

// MPU6050 registers (RM-MPU-6000A-00 rev 4.2)
#define REG_SELF_TEST_X 0x0D           // SELF_TEST_X, _Y, _Z, _A: factory trim codes (register map 4.1)
#define REG_SMPLRT_DIV 0x19
#define REG_CONFIG 0x1A
#define REG_ACCEL_CONFIG 0x1C
#define REG_INT_ENABLE 0x38
#define REG_INT_STATUS 0x3A
#define DATA_RDY 0x01               // INT_ENABLE DATA_RDY_EN / INT_STATUS DATA_RDY_INT (cleared on read)
#define REG_ACCEL_XOUT_H 0x3B
#define REG_PWR_MGMT_1 0x6B
#define REG_WHO_AM_I 0x75
#define PWR_DEVICE_RESET 0x80

// MCUSR must be read and the watchdog stopped before anything else runs, or a
// watchdog reset keeps re-triggering (AVR keeps WDE set after a watchdog reset).
uint8_t mcusr_at_boot __attribute__((section(".noinit")));
// volatile: do_reset() stores it just before an endless loop, which C++ lets the compiler
// assume is never reached; avr-gcc 7.3 (-Os -flto) dropped the plain store, and a RESET
// command came back as a watchdog boot (found running this build in simavr).
volatile uint16_t reset_magic __attribute__((section(".noinit")));
void early_init(void) __attribute__((naked, used, section(".init3")));
void early_init(void) {
  mcusr_at_boot = MCUSR;
  MCUSR = 0;
  wdt_disable();
}

static uint16_t tx_seq = 0;
static uint8_t tx_buf[2 + HEADER_LEN + MAX_PAYLOAD + 2];
static uint8_t rx_buf[HEADER_LEN + MAX_PAYLOAD + 2];
static uint8_t rx_state = 0;  // 0: want SYNC0, 1: want SYNC1, 2: in frame
static uint8_t rx_pos = 0;
static uint8_t rx_need = 0;

static bool streaming = false;
static uint32_t stream_n = 0;
static uint32_t stream_sent = 0;     // the chip's samples since the stream began: the next SAMPLE index
static uint32_t period_us = 1000;  // after reset: DLPF off -> 8 kHz / (1 + 0); we keep 1 kHz max
static uint32_t last_ready_us = 0;   // micros() when the previous new sample was seen
static bool stream_first = true;

uint16_t crc16(const uint8_t *data, uint16_t n) {
  uint16_t crc = CRC16_INIT;
  for (uint16_t i = 0; i < n; i++) {
    crc ^= (uint16_t)data[i] << 8;
    for (uint8_t b = 0; b < 8; b++)
      crc = (crc & 0x8000) ? (uint16_t)((crc << 1) ^ CRC16_POLY) : (uint16_t)(crc << 1);
  }
  return crc ^ CRC16_XOROUT;
}

static void put_u16(uint8_t *p, uint16_t v) { p[0] = v & 0xFF; p[1] = v >> 8; }
static void put_u32(uint8_t *p, uint32_t v) { for (uint8_t i = 0; i < 4; i++) p[i] = (v >> (8 * i)) & 0xFF; }
static uint32_t get_u32(const uint8_t *p) {
  return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}

// Frame: SYNC0 SYNC1 LEN SEQ(2) TYPE TS(4) PAYLOAD CRC(2); CRC over LEN..PAYLOAD.
static void send_frame(uint8_t type, const uint8_t *payload, uint8_t len, uint32_t ts) {
  tx_buf[0] = SYNC0;
  tx_buf[1] = SYNC1;
  tx_buf[2] = len;
  put_u16(tx_buf + 3, tx_seq++);
  tx_buf[5] = type;
  put_u32(tx_buf + 6, ts);
  if (len) memcpy(tx_buf + 2 + HEADER_LEN, payload, len);
  put_u16(tx_buf + 2 + HEADER_LEN + len, crc16(tx_buf + 2, HEADER_LEN + len));
  Serial.write(tx_buf, 2 + HEADER_LEN + len + 2);
}

static void send_ack(uint8_t cmd, uint16_t cmd_seq, const uint8_t *data, uint8_t n) {
  uint8_t p[MAX_PAYLOAD];
  p[0] = cmd;
  put_u16(p + 1, cmd_seq);
  if (n) memcpy(p + 3, data, n);
  send_frame(RSP_ACK, p, 3 + n, micros());
}

static void send_nak(uint8_t cmd, uint16_t cmd_seq, uint8_t err) {
  uint8_t p[4] = {cmd, (uint8_t)(cmd_seq & 0xFF), (uint8_t)(cmd_seq >> 8), err};
  send_frame(RSP_NAK, p, 4, micros());
}

static bool i2c_read(uint8_t reg, uint8_t *dst, uint8_t n) {
  Wire.beginTransmission(MPU_ADDR);
  Wire.write(reg);
  if (Wire.endTransmission(false) != 0) return false;  // repeated start, as the datasheet's burst read
  if (Wire.requestFrom((uint8_t)MPU_ADDR, n) != n) return false;
  for (uint8_t i = 0; i < n; i++) dst[i] = Wire.read();
  return true;
}

static bool i2c_write(uint8_t reg, const uint8_t *src, uint8_t n) {
  Wire.beginTransmission(MPU_ADDR);
  Wire.write(reg);
  Wire.write(src, n);
  return Wire.endTransmission() == 0;
}

static void end_stream() {
  uint8_t p[4];
  put_u32(p, stream_sent);
  streaming = false;
  send_frame(RSP_STREAM_END, p, 4, micros());
}

static void do_identify(uint16_t seq) {
  uint8_t d[16];
  uint8_t who = 0x00;  // 0x00: the chip did not answer on I2C
  i2c_read(REG_WHO_AM_I, &who, 1);
  d[0] = PROTOCOL_VERSION;
  d[1] = FW_VERSION_MAJOR;
  d[2] = FW_VERSION_MINOR;
  d[3] = MPU_ADDR;
  d[4] = who;
  put_u16(d + 5, NVM_SIZE);
  d[7] = NVM_PAGE_SIZE;
  memcpy(d + 8, BRIDGE_SERIAL, 8);
  send_ack(CMD_IDENTIFY, seq, d, 16);
}

static void do_configure(uint16_t seq, const uint8_t *p, uint8_t len) {
  if (len != 3) return send_nak(CMD_CONFIGURE, seq, ERR_BAD_LENGTH);
  uint8_t afs = p[0], dlpf = p[1], div = p[2];
  if (afs > 3 || dlpf > 6) return send_nak(CMD_CONFIGURE, seq, ERR_BAD_ARG);
  uint8_t accel_config = afs << 3, config = dlpf;
  uint8_t back[3];
  if (!i2c_write(REG_SMPLRT_DIV, &div, 1) || !i2c_write(REG_CONFIG, &config, 1) ||
      !i2c_write(REG_ACCEL_CONFIG, &accel_config, 1) || !i2c_read(REG_ACCEL_CONFIG, back, 1) ||
      !i2c_read(REG_CONFIG, back + 1, 1) || !i2c_read(REG_SMPLRT_DIV, back + 2, 1))
    return send_nak(CMD_CONFIGURE, seq, ERR_I2C);
  // sample rate = gyro output rate / (1 + SMPLRT_DIV); gyro output is 8 kHz with
  // the DLPF off (DLPF_CFG 0) and 1 kHz otherwise (register map section 4.2)
  period_us = (dlpf == 0 ? 125UL : 1000UL) * (1UL + div);
  uint8_t d[7] = {back[0], back[1], back[2]};
  put_u32(d + 3, period_us);
  send_ack(CMD_CONFIGURE, seq, d, 7);
}

static void do_stream(uint16_t seq, const uint8_t *p, uint8_t len) {
  if (len != 4) return send_nak(CMD_STREAM, seq, ERR_BAD_LENGTH);
  uint32_t n = get_u32(p);
  if (n == 0) return send_nak(CMD_STREAM, seq, ERR_BAD_ARG);
  uint8_t d[8];
  put_u32(d, n);
  put_u32(d + 4, period_us);
  // samples on the chip's clock: DATA_RDY_INT tells a new sample (register map 4.15-4.17), so
  // none is read twice; enable it and read INT_STATUS once to clear a stale flag
  send_ack(CMD_STREAM, seq, d, 8);
  streaming = true;
  stream_n = n;
  stream_sent = 0;
  stream_first = true;
  uint8_t en = DATA_RDY, st;
  if (!i2c_write(REG_INT_ENABLE, &en, 1) || !i2c_read(REG_INT_STATUS, &st, 1)) end_stream();  // short: 0 sent
}

static void do_read_reg(uint16_t seq, const uint8_t *p, uint8_t len) {
  if (len != 2) return send_nak(CMD_READ_REG, seq, ERR_BAD_LENGTH);
  uint8_t reg = p[0], n = p[1];
  if (n < 1 || n > REG_MAX_COUNT || reg + n > 0x80) return send_nak(CMD_READ_REG, seq, ERR_BAD_ARG);
  uint8_t d[1 + REG_MAX_COUNT];
  d[0] = reg;
  if (!i2c_read(reg, d + 1, n)) return send_nak(CMD_READ_REG, seq, ERR_I2C);
  send_ack(CMD_READ_REG, seq, d, 1 + n);
}

static void do_write_reg(uint16_t seq, const uint8_t *p, uint8_t len) {
  if (len < 2 || len > 1 + REG_MAX_COUNT) return send_nak(CMD_WRITE_REG, seq, ERR_BAD_LENGTH);
  uint8_t reg = p[0], n = len - 1;
  if (reg + n > 0x80) return send_nak(CMD_WRITE_REG, seq, ERR_BAD_ARG);
  uint8_t d[1 + REG_MAX_COUNT];
  d[0] = reg;
  if (!i2c_write(reg, p + 1, n)) return send_nak(CMD_WRITE_REG, seq, ERR_I2C);
  if (reg == REG_PWR_MGMT_1 && (p[1] & PWR_DEVICE_RESET)) delay(100);  // chip resets its registers
  if (!i2c_read(reg, d + 1, n)) return send_nak(CMD_WRITE_REG, seq, ERR_I2C);
  send_ack(CMD_WRITE_REG, seq, d, 1 + n);
}

static void do_nvm_read(uint16_t seq, const uint8_t *p, uint8_t len) {
  if (len != 1) return send_nak(CMD_NVM_READ, seq, ERR_BAD_LENGTH);
  if (p[0] >= NVM_SIZE / NVM_PAGE_SIZE) return send_nak(CMD_NVM_READ, seq, ERR_BAD_ARG);
  uint8_t d[1 + NVM_PAGE_SIZE];
  d[0] = p[0];
  for (uint8_t i = 0; i < NVM_PAGE_SIZE; i++) d[1 + i] = EEPROM.read(p[0] * NVM_PAGE_SIZE + i);
  send_ack(CMD_NVM_READ, seq, d, 1 + NVM_PAGE_SIZE);
}

static void do_nvm_write(uint16_t seq, const uint8_t *p, uint8_t len) {
  if (len != 1 + NVM_PAGE_SIZE) return send_nak(CMD_NVM_WRITE, seq, ERR_BAD_LENGTH);
  if (p[0] >= NVM_SIZE / NVM_PAGE_SIZE) return send_nak(CMD_NVM_WRITE, seq, ERR_BAD_ARG);
  uint16_t base = p[0] * NVM_PAGE_SIZE;
  for (uint8_t i = 0; i < NVM_PAGE_SIZE; i++) {
    EEPROM.update(base + i, p[1 + i]);  // update: skips unchanged cells, saves wear
    wdt_reset();                        // 3.3 ms per changed byte
  }
  for (uint8_t i = 0; i < NVM_PAGE_SIZE; i++)
    if (EEPROM.read(base + i) != p[1 + i]) return send_nak(CMD_NVM_WRITE, seq, ERR_NVM);
  send_ack(CMD_NVM_WRITE, seq, p, 1);
}

// Wait for the chip's next new sample (DATA_RDY_INT) and read it: x, y, z counts.  False: I2C failed
// or no sample within 100 ms.
static bool next_sample(int16_t *xyz) {
  uint8_t b[7];
  uint32_t t0 = millis();
  do {
    if (!i2c_read(REG_INT_STATUS, b, 7)) return false;
    if (b[0] & DATA_RDY) {
      for (uint8_t i = 0; i < 3; i++) xyz[i] = (int16_t)(((uint16_t)b[1 + 2 * i] << 8) | b[2 + 2 * i]);
      return true;
    }
  } while (millis() - t0 < 100);
  return false;
}

// SELF_TEST phase (on/off), n samples at +-8 g (register map 4.1: the accelerometer self-test is
// judged at +-8 g): ACCEL_CONFIG = XA_ST|YA_ST|ZA_ST (on) with AFS_SEL 2, settle, then the sum,
// the sum of squared deviations from the first sample, and the first sample, per axis; and the
// SELF_TEST_X/Y/Z/A registers.  ACCEL_CONFIG is restored afterwards, also on a failure.
static void do_self_test(uint16_t seq, const uint8_t *p, uint8_t len) {
  if (len != 3) return send_nak(CMD_SELF_TEST, seq, ERR_BAD_LENGTH);
  uint8_t on = p[0];
  uint16_t n = p[1] | ((uint16_t)p[2] << 8);
  if (on > 1 || n < 2 || n > SELF_TEST_MAX_N) return send_nak(CMD_SELF_TEST, seq, ERR_BAD_ARG);
  uint8_t saved, cfg = (uint8_t)((on ? 0xE0 : 0x00) | (2 << 3)), en = DATA_RDY;
  if (!i2c_read(REG_ACCEL_CONFIG, &saved, 1)) return send_nak(CMD_SELF_TEST, seq, ERR_I2C);
  bool ok = i2c_write(REG_ACCEL_CONFIG, &cfg, 1) && i2c_write(REG_INT_ENABLE, &en, 1);
  for (uint16_t t = 0; ok && t < SELF_TEST_SETTLE_MS; t += 50) {
    delay(50);
    wdt_reset();
  }
  int32_t sum[3] = {0, 0, 0};
  uint32_t sq[3] = {0, 0, 0};
  int16_t first[3] = {0, 0, 0}, v[3];
  for (uint16_t k = 0; ok && k < n; k++) {
    wdt_reset();
    if (!(ok = next_sample(v))) break;
    if (k == 0) memcpy(first, v, sizeof(first));
    for (uint8_t i = 0; i < 3; i++) {
      int32_t d = (int32_t)v[i] - first[i];
      sum[i] += v[i];
      sq[i] += (uint32_t)d * (uint32_t)d;  // = d^2 mod 2^32, exact for |d| < 65536
    }
  }
  uint8_t d[2 + 12 + 12 + 6 + 4];
  ok = i2c_write(REG_ACCEL_CONFIG, &saved, 1) && ok && i2c_read(REG_SELF_TEST_X, d + 32, 4);
  if (!ok) return send_nak(CMD_SELF_TEST, seq, ERR_I2C);
  put_u16(d, n);
  for (uint8_t i = 0; i < 3; i++) {
    put_u32(d + 2 + 4 * i, (uint32_t)sum[i]);
    put_u32(d + 14 + 4 * i, sq[i]);
    put_u16(d + 26 + 2 * i, (uint16_t)first[i]);
  }
  send_ack(CMD_SELF_TEST, seq, d, sizeof(d));
}

static void do_reset(uint16_t seq) {
  send_ack(CMD_RESET, seq, 0, 0);
  Serial.flush();
  reset_magic = RESET_MAGIC;
  wdt_enable(WDTO_15MS);
  for (;;) {
  }
}

static void handle_frame() {
  uint8_t len = rx_buf[0];
  uint16_t seq = rx_buf[1] | ((uint16_t)rx_buf[2] << 8);
  uint8_t type = rx_buf[3];
  const uint8_t *p = rx_buf + HEADER_LEN;
  if (streaming) end_stream();  // any command ends a running stream, STREAM_END first
  switch (type) {
    case CMD_IDENTIFY: do_identify(seq); break;
    case CMD_CONFIGURE: do_configure(seq, p, len); break;
    case CMD_STREAM: do_stream(seq, p, len); break;
    case CMD_STOP: send_ack(CMD_STOP, seq, 0, 0); break;
    case CMD_READ_REG: do_read_reg(seq, p, len); break;
    case CMD_WRITE_REG: do_write_reg(seq, p, len); break;
    case CMD_NVM_READ: do_nvm_read(seq, p, len); break;
    case CMD_NVM_WRITE: do_nvm_write(seq, p, len); break;
    case CMD_RESET: do_reset(seq); break;
    case CMD_SELF_TEST: do_self_test(seq, p, len); break;
    default: send_nak(type, seq, ERR_UNKNOWN_CMD); break;
  }
}

// Byte-wise receiver.  A bad CRC or oversize LEN drops the frame silently and the
// host retries after its timeout (the bridge cannot trust a damaged SEQ to NAK it).
static void rx_byte(uint8_t b) {
  switch (rx_state) {
    case 0:
      if (b == SYNC0) rx_state = 1;
      break;
    case 1:
      if (b == SYNC1) {
        rx_state = 2;
        rx_pos = 0;
        rx_need = HEADER_LEN + 2;
      } else if (b != SYNC0) {
        rx_state = 0;
      }
      break;
    default:
      rx_buf[rx_pos++] = b;
      if (rx_pos == 1) {
        if (b > MAX_PAYLOAD) {
          rx_state = 0;
          break;
        }
        rx_need = HEADER_LEN + b + 2;
      }
      if (rx_pos == rx_need) {
        rx_state = 0;
        uint16_t got = rx_buf[rx_need - 2] | ((uint16_t)rx_buf[rx_need - 1] << 8);
        if (crc16(rx_buf, rx_need - 2) == got) handle_frame();
      }
      break;
  }
}

// One look at the chip: INT_STATUS and the data registers in one burst (the chip holds its
// registers still during a burst read, so status and data belong together).  The SAMPLE index
// counts the chip's samples: a sample the bridge could not look at in time (a command being
// handled) or could not send (the UART's buffer full: the link is slower than the sample rate)
// is a gap in the index, never a repeated or an unnumbered sample.
static void stream_step() {
  uint8_t p[4 + SAMPLE_BYTES + 1];
  if (!i2c_read(REG_INT_STATUS, p + 3, 1 + SAMPLE_BYTES)) {
    end_stream();  // short STREAM_END: the host sees sent < n and retries the rest
    return;
  }
  if (!(p[3] & DATA_RDY)) return;  // no new sample since the last look
  uint32_t now = micros();
  uint32_t index = 0;  // this sample's number among the chip's samples since the stream began
  if (stream_first) {
    stream_first = false;
  } else {
    uint32_t k = (now - last_ready_us + period_us / 2) / period_us;  // chip samples since the last seen
    index = stream_sent - 1 + (k ? k : 1);
  }
  last_ready_us = now;
  if (index >= stream_n) {
    stream_sent = stream_n;
    end_stream();
    return;
  }
  put_u32(p, index);  // overwrites the INT_STATUS byte: the data follow at p + 4
  if (Serial.availableForWrite() >= (int)(2 + HEADER_LEN + 4 + SAMPLE_BYTES + 2))
    send_frame(RSP_SAMPLE, p, 4 + SAMPLE_BYTES, now);
  // else: dropped here, without waiting for the UART (waiting would miss the chip's next samples)
  stream_sent = index + 1;  // samples accounted for: sent, or skipped (a gap in the index)
  if (stream_sent >= stream_n) end_stream();
}

// I2C bus clear before the TWI takes the pins (NXP UM10204 rev. 7, 3.1.16 "Bus clear"): a reset in the
// middle of a read can leave the MPU-6050 driving SDA low until it has clocked out the rest of its byte;
// up to nine SCL clocks let it finish and release SDA, then a START and a STOP put every slave back to
// idle.  Open-drain by the direction register: a line is driven low (DDR 1, PORT 0) or released (DDR 0,
// PORT 0: no internal pull-up; the module's pull-ups to its 3.3 V supply raise it).  PC4 = SDA (A4),
// PC5 = SCL (A5) on an ATmega328P.
static void i2c_bus_clear() {
  DDRC &= ~(_BV(PC4) | _BV(PC5));
  PORTC &= ~(_BV(PC4) | _BV(PC5));
  delayMicroseconds(10);
  for (uint8_t i = 0; i < 9 && !(PINC & _BV(PC4)); i++) {
    DDRC |= _BV(PC5);   // SCL low
    delayMicroseconds(5);
    DDRC &= ~_BV(PC5);  // SCL released: the slave shifts its next bit
    delayMicroseconds(5);
  }
  DDRC |= _BV(PC4);   // SDA low while SCL is high: START
  delayMicroseconds(5);
  DDRC &= ~_BV(PC4);  // SDA released while SCL is high: STOP
  delayMicroseconds(5);
}

void setup() {
  uint8_t cause = BOOT_POWER_ON;
  if (mcusr_at_boot & _BV(WDRF)) cause = (reset_magic == RESET_MAGIC) ? BOOT_COMMAND : BOOT_WATCHDOG;
  else if (mcusr_at_boot & _BV(EXTRF)) cause = BOOT_EXTERNAL;  // Optiboot clears MCUSR: reads as power-on
  reset_magic = 0;

  Serial.begin(DEFAULT_BAUD);
  i2c_bus_clear();
  Wire.begin();
  // Wire.begin() turns the AVR's internal pull-ups on (to 5 V on a 5 V Uno: above the MPU-6050's 3.3 V
  // supply and its 3.3 V I/O when the module has no level shifter); the bus is pulled up by the module
  PORTC &= ~(_BV(PC4) | _BV(PC5));
  Wire.setClock(I2C_CLOCK_HZ);
  Wire.setWireTimeout(I2C_TIMEOUT_US, true);  // a stuck bus fails the transfer instead of hanging
  uint8_t r = PWR_DEVICE_RESET;                // known state: all registers default, chip asleep
  i2c_write(REG_PWR_MGMT_1, &r, 1);
  delay(100);

  // known-answer self-test of the CRC; a mismatch means a broken build: stay silent
  if (crc16(TEST_FRAME + 2, sizeof(TEST_FRAME) - 4) != TEST_FRAME_CRC) for (;;) {
    }

  uint8_t boot[4] = {PROTOCOL_VERSION, cause, FW_VERSION_MAJOR, FW_VERSION_MINOR};
  send_frame(RSP_BOOT, boot, 4, micros());
  wdt_enable(WDTO_1S);  // an I2C or UART hang reboots the bridge; the host sees BOOT
}

void loop() {
  wdt_reset();
  while (Serial.available() > 0) rx_byte((uint8_t)Serial.read());
  if (streaming) stream_step();
}
