// A TMC2209 stepper driver on a board's UART (single-wire PDN_UART) and STEP/DIR/ENN pins, as its
// datasheet (Trinamic TMC2209 rev. 1.09) describes the parts the joint firmware relies on.
//
// The wire: the Pico's TX reaches PDN_UART through 1 kOhm and its RX listens to the same wire, so
// every character the Pico sends comes back on its RX when its stop bit ends (the echo), and the
// driver's replies arrive there too. (Our PL011 calls `onByte` at the end of each stop bit.)
//
// The UART interface (datasheet section 4):
// * datagrams: write 05 | node | reg|0x80 | 4 data bytes MSB first | CRC (8 bytes); read request
//   05 | node | reg | CRC (4 bytes); reply 05 | FF | reg | 4 data bytes | CRC (8 bytes). The sync
//   byte's high nibble is reserved (not checked); the CRC is CRC-8, polynomial x^8+x^2+x+1, initial
//   0, every byte fed LSB first (section 4.2);
// * a datagram with a bad CRC or another node address is ignored; a pause of more than 63 bit
//   times inside a datagram resets the receiver (section 4.1.1);
// * IFCNT counts valid writes modulo 256; reads change nothing;
// * a reply starts SENDDELAY bit times after the request's last stop bit (NODECONF bits 11:8:
//   0-1 -> 8, 2-3 -> 24, 4-5 -> 40, ... 14-15 -> 120) and its characters follow back to back at the
//   baud rate of the request (the driver measures it from the sync nibble).
// Registers: GCONF, GSTAT (write 1 to clear, reset flag set at power-up), IFCNT, NODECONF, IOIN
// (live ENN/MS1/MS2/PDN_UART/STEP/DIR pins, VERSION 0x21), IHOLD_IRUN, TPOWERDOWN, TSTEP,
// TPWMTHRS, TCOOLTHRS, SGTHRS, COOLCONF, MSCNT, CHOPCONF, DRV_STATUS (stst, stealth, CS_ACTUAL),
// PWMCONF; others read as 0. Write-only registers read as 0 (the datasheet leaves that open).
// Stepping: with GCONF.mstep_reg_select the microstep resolution is CHOPCONF.MRES, otherwise the
// MS1/MS2 pins (which are the node address: 00 -> 8, 01 -> 2, 10 -> 4, 11 -> 16); each STEP rising
// edge (both edges with CHOPCONF.dedge) moves the microstep counter by 256/microsteps toward DIR
// (high: up), reversed by GCONF.shaft; nothing moves while ENN is high or CHOPCONF.TOFF is 0.
// Not modelled: VACTUAL (internal step generator), StallGuard, CoolStep, OTP, the analog side.

export const REG = {
  GCONF: 0x00, GSTAT: 0x01, IFCNT: 0x02, NODECONF: 0x03, IOIN: 0x06, IHOLD_IRUN: 0x10,
  TPOWERDOWN: 0x11, TSTEP: 0x12, TPWMTHRS: 0x13, TCOOLTHRS: 0x14, VACTUAL: 0x22, SGTHRS: 0x40,
  SG_RESULT: 0x41, COOLCONF: 0x42, MSCNT: 0x6a, CHOPCONF: 0x6c, DRV_STATUS: 0x6f, PWMCONF: 0x70,
};
const NAMES = Object.fromEntries(Object.entries(REG).map(([k, v]) => [v, k]));

const RESET = {
  [REG.GCONF]: 0x00000101, [REG.GSTAT]: 0x1, [REG.TPOWERDOWN]: 20, [REG.CHOPCONF]: 0x10000053,
  [REG.PWMCONF]: 0xc10d0024, [REG.IHOLD_IRUN]: 0x00001f00 | (1 << 16) | 16,
};
const READABLE = new Set([REG.GCONF, REG.GSTAT, REG.IFCNT, REG.IOIN, REG.TSTEP, REG.SG_RESULT,
  REG.MSCNT, REG.CHOPCONF, REG.DRV_STATUS, REG.PWMCONF]);
const GCONF_SHAFT = 1 << 3;
const GCONF_MSTEP_REG_SELECT = 1 << 7;
const GCONF_EN_SPREADCYCLE = 1 << 2;
const CHOP_DEDGE = 1 << 29;
const FCLK = 12e6; // Hz, the internal clock (nominal)
const STANDSTILL_CLOCKS = 2 ** 20;
const MS_PIN_MICROSTEPS = [8, 2, 4, 16]; // index MS2 << 1 | MS1

/** CRC of `bytes` as the TMC22xx computes it. */
export function tmcCrc(bytes) {
  let crc = 0;
  for (let byte of bytes) {
    for (let i = 0; i < 8; i++) {
      crc = ((crc >> 7) ^ (byte & 1)) ? ((crc << 1) ^ 0x07) & 0xff : (crc << 1) & 0xff;
      byte >>= 1;
    }
  }
  return crc;
}

export function sendDelayBits(nodeconf) {
  const d = (nodeconf >> 8) & 0xf;
  return d < 2 ? 8 : (2 * (d >> 1) + 1) * 8;
}

export class TMC2209 {
  /**
   * @param board  a chip/src/board.mjs Board
   * @param opts   { uart: 1, node: 0, step: 10, dir: 11, enn: 12 }
   */
  constructor(board, { uart = 1, node = 0, step = 10, dir = 11, enn = 12 } = {}) {
    this.board = board;
    this.uart = board.rp2040.uart[uart];
    this.node = node;
    this.pins = { step, dir, enn };
    this.regs = new Map(Object.entries(RESET).map(([k, v]) => [Number(k), v]));
    this.ifcnt = 0;
    this.writes = []; // [reg, value, nanos] of every accepted write
    this.rx = [];
    this.lastByteNanos = -Infinity;
    this.replyFreeNanos = 0; // the wire is ours again after the reply in flight
    // Fault injection: counts of the next datagrams to spoil.
    this.faults = { badCrc: 0, silent: 0, ignoreWrites: 0 };
    this.absent = false; // no driver on the wire (the echo stays)
    this.echo = true; // RX wired to PDN_UART
    this.position = 0; // microstep counter in 1/256 full steps (unbounded; MSCNT is it mod 1024)
    this.steps = 0; // STEP edges taken
    this.lastStepNanos = -Infinity;
    this.tstepClocks = 0xfffff;
    this.onStep = null; // (position, nanos) after every microstep
    this.uart.onByte = (byte) => this.wireByte(byte);
    const gpio = board.rp2040.gpio;
    gpio[step].addListener((value, last) => this.stepEdge(value, last));
  }

  reg(addr) {
    return this.regs.get(addr) ?? 0;
  }

  get nanos() {
    return this.board.pio ? this.board.pio.nanos : this.board.nanos;
  }

  /** Bit time of the Pico's UART (the driver locks on to it). */
  get bitNanos() {
    return (16 * this.uart.baudDivider * 1e9) / this.board.rp2040.clkPeri;
  }

  // ---- the wire ----

  wireByte(byte) {
    if (this.echo) this.uart.feedByte(byte);
    if (!this.absent) this.receive(byte);
  }

  receive(byte) {
    const now = this.board.nanos;
    if (now - this.lastByteNanos > 63 * this.bitNanos + 10 * this.bitNanos) this.rx = [];
    this.lastByteNanos = now;
    const rx = this.rx;
    if (rx.length === 0 && (byte & 0x0f) !== 0x05) return; // wait for a sync nibble
    rx.push(byte);
    if (rx.length < 3) return;
    const length = rx[2] & 0x80 ? 8 : 4;
    if (rx.length < length) return;
    this.rx = [];
    this.datagram(rx, now);
  }

  datagram(bytes, endNanos) {
    const n = bytes.length;
    if (tmcCrc(bytes.slice(0, n - 1)) !== bytes[n - 1] || bytes[1] !== this.node) return;
    const addr = bytes[2] & 0x7f;
    if (n === 8) {
      if (this.faults.ignoreWrites > 0) {
        this.faults.ignoreWrites--;
        return;
      }
      this.write(addr, ((bytes[3] << 24) | (bytes[4] << 16) | (bytes[5] << 8) | bytes[6]) >>> 0);
      return;
    }
    if (this.faults.silent > 0) {
      this.faults.silent--;
      return;
    }
    const value = this.read(addr);
    const reply = [0x05, 0xff, addr, value >>> 24, (value >>> 16) & 0xff, (value >>> 8) & 0xff, value & 0xff];
    reply.push(tmcCrc(reply));
    if (this.faults.badCrc > 0) {
      this.faults.badCrc--;
      reply[7] ^= 0x5a;
    }
    const bit = this.bitNanos;
    const start = Math.max(endNanos + sendDelayBits(this.reg(REG.NODECONF)) * bit, this.replyFreeNanos);
    reply.forEach((b, i) => {
      this.board.afterNanos(start + (i + 1) * 10 * bit - this.board.nanos, () => this.uart.feedByte(b));
    });
    this.replyFreeNanos = start + 80 * bit;
  }

  // ---- registers ----

  write(addr, value) {
    this.ifcnt = (this.ifcnt + 1) & 0xff;
    this.writes.push([addr, value, this.board.nanos]);
    if (addr === REG.GSTAT) {
      this.regs.set(addr, this.reg(addr) & ~value & 0x7);
    } else if (addr !== REG.IFCNT && addr !== REG.IOIN && addr !== REG.TSTEP && addr !== REG.MSCNT
      && addr !== REG.DRV_STATUS && addr !== REG.SG_RESULT) {
      this.regs.set(addr, value);
    }
  }

  read(addr) {
    if (!READABLE.has(addr)) return 0;
    switch (addr) {
      case REG.IFCNT: return this.ifcnt;
      case REG.IOIN: return this.ioin();
      case REG.TSTEP: return this.standstill() ? 0xfffff : this.tstepClocks;
      case REG.MSCNT: return ((this.position % 1024) + 1024) % 1024;
      case REG.DRV_STATUS: return this.drvStatus();
      default: return this.reg(addr);
    }
  }

  /** The level the driver sees: driven high, or undriven with the pad's pull-up. */
  pinHigh(pin) {
    const v = this.board.rp2040.gpio[pin].value;
    return v === 1 || v === 3; // GPIOPinState.High, InputPullUp
  }

  ioin() {
    const ms1 = this.node & 1;
    const ms2 = (this.node >> 1) & 1;
    return ((0x21 << 24) | (this.pinHigh(this.pins.dir) ? 1 << 9 : 0)
      | (this.pinHigh(this.pins.step) ? 1 << 7 : 0) | (1 << 6) | (ms2 << 3) | (ms1 << 2)
      | (this.enabled() ? 0 : 1)) >>> 0;
  }

  standstill() {
    return (this.nanos - this.lastStepNanos) * (FCLK / 1e9) >= STANDSTILL_CLOCKS;
  }

  drvStatus() {
    const { ihold, irun } = this.currents();
    const still = this.standstill();
    const powerdown = (STANDSTILL_CLOCKS + this.reg(REG.TPOWERDOWN) * 2 ** 18) / FCLK * 1e9;
    const held = still && this.nanos - this.lastStepNanos >= powerdown;
    const tpwmthrs = this.reg(REG.TPWMTHRS);
    const stealth = !(this.reg(REG.GCONF) & GCONF_EN_SPREADCYCLE)
      && (tpwmthrs === 0 || still || this.tstepClocks >= tpwmthrs);
    return (((still ? 1 : 0) << 31) | ((stealth ? 1 : 0) << 30) | ((held ? ihold : irun) << 16)) >>> 0;
  }

  // ---- stepping ----

  microsteps() {
    if (this.reg(REG.GCONF) & GCONF_MSTEP_REG_SELECT) {
      return 256 >> Math.min(8, (this.reg(REG.CHOPCONF) >>> 24) & 0xf);
    }
    return MS_PIN_MICROSTEPS[this.node & 3];
  }

  enabled() {
    return !this.pinHigh(this.pins.enn);
  }

  powered() {
    return this.enabled() && (this.reg(REG.CHOPCONF) & 0xf) !== 0;
  }

  currents() {
    const v = this.reg(REG.IHOLD_IRUN);
    return { ihold: v & 0x1f, irun: (v >> 8) & 0x1f, iholddelay: (v >> 16) & 0xf };
  }

  stepEdge(value, last) {
    const rising = value === 1 && last !== 1;
    const falling = value !== 1 && last === 1;
    if (!(rising || (falling && this.reg(REG.CHOPCONF) & CHOP_DEDGE))) return;
    if (!this.powered()) return;
    const now = this.nanos;
    if (now > this.lastStepNanos) this.tstepClocks = Math.min(0xfffff, Math.round((now - this.lastStepNanos) * FCLK / 1e9));
    this.lastStepNanos = now;
    let up = this.pinHigh(this.pins.dir);
    if (this.reg(REG.GCONF) & GCONF_SHAFT) up = !up;
    const delta = 256 / this.microsteps();
    this.position += up ? delta : -delta;
    this.steps++;
    this.onStep?.(this.position, now);
  }

  /** The register file and derived settings, for tests (JSON-friendly). */
  state() {
    const regs = {};
    for (const [addr, value] of this.regs) regs[NAMES[addr] ?? `0x${addr.toString(16)}`] = value;
    const chop = this.reg(REG.CHOPCONF);
    return {
      regs, ifcnt: this.ifcnt, writes: this.writes.map(([a, v, t]) => [NAMES[a] ?? a, v, t]),
      microsteps: this.microsteps(), ...this.currents(), vsense: (chop >> 17) & 1,
      shaft: !!(this.reg(REG.GCONF) & GCONF_SHAFT), enabled: this.enabled(), position: this.position,
      steps: this.steps, faults: { ...this.faults }, absent: this.absent,
    };
  }
}
