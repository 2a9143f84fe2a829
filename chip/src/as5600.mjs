// An AS5600 magnetic angle sensor as an I2C target (ams AS5600 datasheet v1-06, registers 0x00-0xFF).
//
// * Address 0x36. A write sets the address pointer with its first byte; further bytes go to the
//   registers from there, the pointer incrementing. Only ZPOS (0x01-0x02), MPOS (0x03-0x04), MANG
//   (0x05-0x06) and CONF (0x07-0x08) are writable (volatile; BURN is accepted and ignored).
// * A read starts at the pointer and increments it, except that RAW ANGLE (0x0C), ANGLE (0x0E) and
//   MAGNITUDE (0x1B) read from their high byte do not move the pointer on: after the low byte it
//   returns to the high byte, so they can be re-read without a write. The 12-bit value is latched
//   when its high byte is read, so the two bytes of one read belong together.
// * STATUS (0x0B): MD (bit 5) magnet detected, ML (bit 4) too weak, MH (bit 3) too strong; AGC 0x1A.
// * ANGLE: RAW ANGLE minus ZPOS, scaled to the range MPOS - ZPOS (or MANG) when one is set.
// The angle comes from `source()` in counts (0..4095, any real number: it is wrapped and rounded),
// e.g. the rotor model. Fault injection: `nack` (the next n transfers are not acknowledged),
// `absent`, `noise` (uniform +/- counts, from a seeded generator so runs repeat). The output filter
// (CONF.SF/FTH) is not modelled: the registers show the angle without lag.
export const AS5600_ADDRESS = 0x36;
const MD = 0x20;
const ML = 0x10;
const MH = 0x08;
const WRITABLE = new Set([0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x07, 0x08]);
const LATCHED = { 0x0c: 'raw', 0x0e: 'angle', 0x1b: 'magnitude' };
const MASKS = { 0x01: 0x0f, 0x03: 0x0f, 0x05: 0x0f, 0x07: 0x3f };

export class AS5600 {
  constructor(source = () => 0, { seed = 1 } = {}) {
    this.source = source;
    this.mem = new Uint8Array(256);
    this.pointer = 0;
    this.wrote = 0; // bytes of the write in progress (the first one sets the pointer)
    this.latch = 0;
    this.magnet = 'ok'; // 'ok' | 'weak' | 'strong' | 'none'
    this.agc = 0x80;
    this.magnitude = 0x0a00;
    this.nack = 0;
    this.absent = false;
    this.noise = 0;
    this.rng = seed >>> 0 || 1;
    this.transfers = 0;
    this.reads = 0;
  }

  random() { // xorshift32 in [0, 1)
    let x = this.rng;
    x ^= x << 13; x >>>= 0; x ^= x >>> 17; x ^= x << 5; x >>>= 0;
    this.rng = x;
    return x / 2 ** 32;
  }

  rawAngle() {
    let counts = this.source();
    if (this.noise) counts += (this.random() * 2 - 1) * this.noise;
    return ((Math.round(counts) % 4096) + 4096) % 4096;
  }

  word(addr) {
    return ((this.mem[addr] & 0x0f) << 8) | this.mem[addr + 1];
  }

  scaledAngle(raw) {
    const zpos = this.word(0x01);
    const mpos = this.word(0x03);
    const mang = this.word(0x05);
    const span = mpos ? (mpos - zpos + 4096) % 4096 : mang;
    const rel = (raw - zpos + 4096) % 4096;
    if (!span) return rel;
    return Math.min(4095, Math.floor((rel * 4096) / span));
  }

  status() {
    return { ok: MD, weak: MD | ML, strong: MD | MH, none: ML }[this.magnet];
  }

  // ---- I2C target ----

  start(read) {
    if (this.absent) return false;
    if (this.nack > 0) {
      this.nack--;
      return false;
    }
    this.transfers++;
    this.wrote = read ? -1 : 0;
    if (read) this.reads++;
    return true;
  }

  write(byte) {
    if (this.wrote === 0) {
      this.pointer = byte;
    } else if (WRITABLE.has(this.pointer)) {
      this.mem[this.pointer] = byte & (MASKS[this.pointer] ?? 0xff);
      this.pointer = (this.pointer + 1) & 0xff;
    } else {
      this.pointer = (this.pointer + 1) & 0xff;
    }
    this.wrote++;
    return true;
  }

  read() {
    const p = this.pointer;
    if (LATCHED[p]) {
      const raw = this.rawAngle();
      this.latch = p === 0x0c ? raw : p === 0x0e ? this.scaledAngle(raw) : this.magnitude;
      this.pointer = p + 1;
      return (this.latch >> 8) & 0x0f;
    }
    if (LATCHED[p - 1]) {
      this.pointer = p - 1;
      return this.latch & 0xff;
    }
    this.pointer = (p + 1) & 0xff;
    switch (p) {
      case 0x0b: return this.status();
      case 0x1a: return this.agc;
      default: return this.mem[p];
    }
  }

  stop() {}

  state() {
    return {
      conf: ((this.mem[0x07] & 0x3f) << 8) | this.mem[0x08], zpos: this.word(0x01), mpos: this.word(0x03),
      mang: this.word(0x05), magnet: this.magnet, raw: this.rawAngle(), transfers: this.transfers,
      reads: this.reads, nack: this.nack, absent: this.absent, noise: this.noise,
    };
  }
}
