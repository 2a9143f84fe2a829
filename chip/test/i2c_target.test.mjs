// The I2C target block against the RP2040 datasheet (section 4.3), register by register, with no
// firmware: the test plays the CPU, a bit-timed controller plays the bus.
import assert from 'node:assert/strict';
import { test } from 'node:test';
import { RP2040 } from 'rp2040js';
import {
  ABRT_SLVFLUSH_TXFIFO,
  installI2C,
  R_RD_REQ,
  R_RESTART_DET,
  R_RX_DONE,
  R_RX_FULL,
  R_RX_OVER,
  R_START_DET,
  R_STOP_DET,
  R_TX_ABRT,
} from '../src/i2c_target.mjs';
import { I2CController, wireBits } from '../src/i2c_controller.mjs';

const BASE = 0x40044000;
const IC_CON = 0x00;
const IC_SAR = 0x08;
const IC_DATA_CMD = 0x10;
const IC_INTR_STAT = 0x2c;
const IC_INTR_MASK = 0x30;
const IC_RAW_INTR_STAT = 0x34;
const IC_RX_TL = 0x38;
const IC_TX_TL = 0x3c;
const IC_CLR_INTR = 0x40;
const IC_CLR_RD_REQ = 0x50;
const IC_CLR_TX_ABRT = 0x54;
const IC_CLR_STOP_DET = 0x60;
const IC_CLR_START_DET = 0x64;
const IC_ENABLE = 0x6c;
const IC_STATUS = 0x70;
const IC_RXFLR = 0x78;
const IC_TX_ABRT_SOURCE = 0x80;
const ADDR = 0x11;
const HLD = 1 << 9;
const STOP_DET_IFADDRESSED = 1 << 7;
const MICROPYTHON_MASK = (1 << 10) | (1 << 9) | (1 << 7) | (1 << 6) | (1 << 5) | (1 << 2);

function board({ con = HLD | STOP_DET_IFADDRESSED, khz = 400 } = {}) {
  const mcu = new RP2040();
  mcu.logger = { debug() {}, info() {}, warn() {}, error() {} };
  installI2C(mcu);
  const reg = {
    read: (off) => mcu.readUint32(BASE + off),
    write: (off, v) => mcu.writeUint32(BASE + off, v),
  };
  // As MicroPython's rp2 I2CTarget initialises the block.
  reg.write(IC_ENABLE, 0);
  reg.write(IC_CON, con);
  reg.write(IC_SAR, ADDR);
  reg.write(IC_TX_TL, 1);
  reg.write(IC_RX_TL, 0);
  reg.read(IC_CLR_INTR);
  reg.write(IC_INTR_MASK, MICROPYTHON_MASK);
  reg.write(IC_ENABLE, 1);
  const bus = new I2CController(mcu.clock, { khz }).attach(mcu.i2c[0]);
  return { mcu, reg, bus };
}

/** Advance emulated time in 100 ns steps, calling cpu(nowNs) each step, until the transfer ends. */
function run(mcu, bus, spec, cpu = () => {}) {
  let result = null;
  bus.transfer(spec, (r) => (result = r));
  for (let i = 0; i < 2e6 && !result; i++) {
    mcu.clock.tick(100);
    cpu(mcu.clock.nanos);
  }
  assert.ok(result, 'transfer did not finish');
  return result;
}

test('IC_INTR_MASK is a register and gates IC_INTR_STAT and the NVIC line', () => {
  const { mcu, reg, bus } = board();
  assert.equal(reg.read(IC_INTR_MASK), MICROPYTHON_MASK);
  run(mcu, bus, { addr: ADDR, write: [1] });
  assert.equal(reg.read(IC_RAW_INTR_STAT) & (R_START_DET | R_STOP_DET | R_RX_FULL), R_START_DET | R_STOP_DET | R_RX_FULL);
  assert.ok(mcu.core.pendingInterrupts & (1 << 23));
  reg.write(IC_INTR_MASK, 0);
  assert.equal(reg.read(IC_INTR_STAT), 0);
  assert.equal(mcu.core.pendingInterrupts & (1 << 23), 0);
  reg.write(IC_INTR_MASK, R_STOP_DET);
  assert.equal(reg.read(IC_INTR_STAT), R_STOP_DET);
});

test('only IC_SAR is ACKed; another address is NAKed and leaves no data or STOP_DET', () => {
  const { mcu, reg, bus } = board();
  const other = run(mcu, bus, { addr: 0x12, write: [1, 2] });
  assert.equal(other.ack, false);
  assert.equal(reg.read(IC_RXFLR), 0);
  const raw = reg.read(IC_RAW_INTR_STAT);
  assert.ok(raw & R_START_DET, 'START_DET is raised for any START');
  assert.equal(raw & R_STOP_DET, 0, 'STOP_DET_IFADDRESSED: no STOP_DET when not addressed');
  const mine = run(mcu, bus, { addr: ADDR, write: [1, 2] });
  assert.equal(mine.ack, true);
  assert.equal(reg.read(IC_RXFLR), 2);
  assert.ok(reg.read(IC_RAW_INTR_STAT) & R_STOP_DET);
});

test('received bytes go to the RX FIFO; FIRST_DATA_BYTE marks the first; RX_FULL is a level', () => {
  const { mcu, reg, bus } = board();
  reg.write(IC_RX_TL, 1); // RX_FULL above 1 entry
  run(mcu, bus, { addr: ADDR, write: [0x0f, 0xaa, 0x55] });
  assert.equal(reg.read(IC_RXFLR), 3);
  assert.ok(reg.read(IC_STATUS) & (1 << 3), 'RFNE');
  assert.ok(reg.read(IC_RAW_INTR_STAT) & R_RX_FULL);
  assert.equal(reg.read(IC_DATA_CMD), 0x0f | (1 << 11));
  assert.ok(reg.read(IC_RAW_INTR_STAT) & R_RX_FULL, 'still 2 entries: above IC_RX_TL');
  assert.equal(reg.read(IC_DATA_CMD), 0xaa);
  assert.equal(reg.read(IC_RAW_INTR_STAT) & R_RX_FULL, 0, '1 entry: not above IC_RX_TL');
  assert.equal(reg.read(IC_DATA_CMD), 0x55);
  assert.equal(reg.read(IC_STATUS) & (1 << 3), 0);
});

test('a write with nobody holding SCL takes exactly its wire time, at 100 kHz, 400 kHz and 1 MHz', () => {
  for (const khz of [100, 400, 1000]) {
    const { mcu, bus } = board({ khz });
    const r = run(mcu, bus, { addr: ADDR, write: [1, 2, 3, 4, 5] });
    assert.equal(r.heldNs, 0);
    assert.equal(r.bits, wireBits(5, 0));
    assert.equal(r.bits, 56);
    assert.ok(Math.abs(r.totalNs - (56 * 1e6) / khz) < 1, `${khz} kHz: ${r.totalNs} ns`);
  }
});

test('RX_FIFO_FULL_HLD_CTRL: a full RX FIFO holds SCL until software reads, and loses nothing', () => {
  const { mcu, reg, bus } = board();
  const sent = Array.from({ length: 20 }, (_, i) => i + 1);
  const got = [];
  let drainAt = null;
  const r = run(mcu, bus, { addr: ADDR, write: sent }, (now) => {
    if (drainAt === null && reg.read(IC_RXFLR) === 16) drainAt = now + 200_000;
    if (drainAt !== null && now >= drainAt) {
      while (reg.read(IC_STATUS) & (1 << 3)) got.push(reg.read(IC_DATA_CMD) & 0xff);
    }
  });
  while (reg.read(IC_STATUS) & (1 << 3)) got.push(reg.read(IC_DATA_CMD) & 0xff);
  assert.deepEqual(got, sent);
  // The 16th byte filled the FIFO; the 17th is held from its 8th bit (9 bit times later).
  assert.ok(Math.abs(r.heldNs - (200_000 - 9 * 2500)) < 200, `held ${r.heldNs} ns`);
  assert.equal(reg.read(IC_RAW_INTR_STAT) & R_RX_OVER, 0);
});

test('without RX_FIFO_FULL_HLD_CTRL a full RX FIFO raises RX_OVER and drops the byte', () => {
  const { mcu, reg, bus } = board({ con: STOP_DET_IFADDRESSED });
  const r = run(mcu, bus, { addr: ADDR, write: Array.from({ length: 18 }, (_, i) => i) });
  assert.equal(r.heldNs, 0);
  assert.equal(reg.read(IC_RXFLR), 16);
  assert.ok(reg.read(IC_RAW_INTR_STAT) & R_RX_OVER);
});

test('a read raises RD_REQ and holds SCL until IC_DATA_CMD is written; the NAK raises RX_DONE', () => {
  const { mcu, reg, bus } = board();
  let answerAt = null;
  const r = run(mcu, bus, { addr: ADDR, write: [0x0f], read: 2 }, (now) => {
    const raw = reg.read(IC_RAW_INTR_STAT);
    if (raw & R_RD_REQ && answerAt === null) answerAt = now + 300_000;
    if (answerAt !== null && now >= answerAt && raw & R_RD_REQ) {
      reg.read(IC_CLR_RD_REQ);
      reg.write(IC_DATA_CMD, 0x4f);
      reg.write(IC_DATA_CMD, 0x0c);
    }
  });
  assert.deepEqual(r.data, [0x4f, 0x0c]);
  assert.ok(r.heldNs >= 300_000 && r.heldNs < 300_300, `held ${r.heldNs} ns`);
  assert.ok(Math.abs(r.totalNs - r.heldNs - wireBits(1, 2) * 2500) < 1);
  const raw = reg.read(IC_RAW_INTR_STAT);
  assert.ok(raw & R_RX_DONE);
  assert.ok(raw & R_RESTART_DET, 'repeated START while addressed');
});

test('a new read flushes stale TX data with ABRT_SLVFLUSH_TXFIFO; the FIFO stays flushed until IC_CLR_TX_ABRT', () => {
  const { mcu, reg, bus } = board();
  reg.write(IC_DATA_CMD, 0xee); // a byte left over (MicroPython's pad after the NAK)
  let phase = 0;
  const r = run(mcu, bus, { addr: ADDR, read: 1 }, () => {
    const raw = reg.read(IC_RAW_INTR_STAT);
    if (phase === 0 && raw & R_RD_REQ) {
      assert.ok(raw & R_TX_ABRT);
      const source = reg.read(IC_TX_ABRT_SOURCE);
      assert.ok(source & ABRT_SLVFLUSH_TXFIFO);
      assert.equal(source >>> 23, 1, 'TX_FLUSH_CNT');
      reg.write(IC_DATA_CMD, 0x11); // ignored: still flushed
      assert.ok(reg.read(IC_STATUS) & (1 << 2), 'TFE');
      reg.read(IC_CLR_TX_ABRT);
      reg.read(IC_CLR_RD_REQ);
      reg.write(IC_DATA_CMD, 0x22);
      phase = 1;
    }
  });
  assert.deepEqual(r.data, [0x22]);
});

test('IC_STATUS shows SLV_ACTIVITY while addressed; START_DET/STOP_DET clear by their registers', () => {
  const { mcu, reg, bus } = board();
  let active = false;
  run(mcu, bus, { addr: ADDR, write: [1, 2] }, () => {
    if (reg.read(IC_STATUS) & (1 << 6)) active = true;
  });
  assert.ok(active);
  assert.equal(reg.read(IC_STATUS) & (1 << 6), 0);
  assert.equal(reg.read(IC_CLR_START_DET), 1);
  assert.equal(reg.read(IC_CLR_STOP_DET), 1);
  assert.equal(reg.read(IC_RAW_INTR_STAT) & (R_START_DET | R_STOP_DET), 0);
});

test('IC_CLR_INTR clears RESTART_DET with the others', () => {
  const { mcu, reg, bus } = board();
  run(mcu, bus, { addr: ADDR, write: [1], read: 1 }, () => {
    if (reg.read(IC_RAW_INTR_STAT) & R_RD_REQ) {
      reg.read(IC_CLR_RD_REQ);
      reg.write(IC_DATA_CMD, 7);
    }
  });
  assert.ok(reg.read(IC_RAW_INTR_STAT) & R_RESTART_DET);
  reg.read(IC_CLR_INTR);
  assert.equal(reg.read(IC_RAW_INTR_STAT) & (R_RESTART_DET | R_STOP_DET | R_START_DET | R_RX_DONE), 0);
});

test('a target that never answers RD_REQ: the controller gives up after its stretch timeout, the bus stays busy until SCL is let go', () => {
  const { mcu, reg, bus } = board();
  bus.stretchTimeoutNs = 1e6;
  const first = run(mcu, bus, { addr: ADDR, write: [1], read: 1 });
  assert.equal(first.timedOut, true);
  assert.equal(first.ack, false);
  assert.ok(first.heldNs >= 1e6 && first.heldNs < 1.01e6);
  assert.ok(mcu.i2c[0].holdingScl, 'the target still holds SCL');
  const second = run(mcu, bus, { addr: ADDR, write: [2] });
  assert.equal(second.timedOut, true, 'no START while SCL is held');
  reg.write(IC_DATA_CMD, 0x33); // software answers at last: SCL is released
  assert.equal(mcu.i2c[0].holdingScl, false);
  const third = run(mcu, bus, { addr: ADDR, write: [3] });
  assert.equal(third.ack, true);
  assert.equal(third.timedOut, false);
});
