// Stock MicroPython's machine.I2CTarget (rp2 driver) on our I2C target block, driven by the
// bit-timed controller: the event order and mem= semantics MicroPython documents and tests
// (reference/i2c-facts.md 1.4, 1.5), clock stretching by a slow handler, and the IRQ meter.
import assert from 'node:assert/strict';
import { before, test } from 'node:test';
import { Board, World } from '../src/board.mjs';
import { JointBus } from '../src/joint_bus.mjs';
import { skipNoBinaries, usbText } from './helpers.mjs';

const ADDR = 0x41;
let board;
let world;
let bus;
let usb;

function py(code) {
  usb.text = '';
  // The output follows a marker the echoed source does not contain, and ends at the prompt.
  board.usbWrite(Buffer.from(`\x05print("<" + "<<")\n${code}\x04`));
  assert.ok(world.runUntilTrue(() => /<<<\r\n[\s\S]*>>> $/.test(usb.text), 5e9), usb.text);
  const text = usb.text.slice(usb.text.lastIndexOf('<<<\r\n') + 5, -4).replace(/\r/g, '').trim();
  assert.doesNotMatch(text, /Traceback/, text);
  return text;
}

function xfer(spec) {
  let result = null;
  bus.controller.transfer(spec, (r) => (result = r));
  assert.ok(world.runUntilTrue(() => result, 1e9), `transfer ${JSON.stringify(spec)} did not end`);
  return result;
}

before(() => {
  if (skipNoBinaries) return;
  board = new Board();
  bus = new JointBus(board, { khz: 400 });
  world = new World();
  world.add(board);
  usb = usbText(board);
  assert.ok(world.runUntilTrue(() => board.usbConnected, 2e9));
  board.usbWrite(Buffer.from('\r'));
  assert.ok(world.runUntilTrue(() => usb.text.includes('>>> '), 1e9));
});

const EVENTS = `
import machine, time
from machine import I2CTarget
ev = bytearray(64); n = [0]; rx = bytearray(64); rn = [0]; buf = bytearray(16); one = bytearray(1)
slow = [0]
def h(t):
    f = t.irq().flags()
    ev[n[0]] = f; n[0] += 1
    if f & I2CTarget.IRQ_WRITE_REQ:
        k = t.readinto(buf)
        for i in range(k):
            rx[rn[0]] = buf[i]; rn[0] += 1
    if f & I2CTarget.IRQ_READ_REQ:
        if slow[0]:
            time.sleep_us(slow[0])
        one[0] = 0x60 + n[0]
        t.write(one)
def events():
    out = list(ev[:n[0]]), bytes(rx[:rn[0]])
    n[0] = 0; rn[0] = 0
    return out
`;

test('irq mode, hard: the event order MicroPython documents for rp2', { skip: skipNoBinaries }, () => {
  py(`${EVENTS}
t = I2CTarget(0, ${ADDR}, scl=machine.Pin(5), sda=machine.Pin(4))
t.irq(h, trigger=63, hard=True)`);
  // writeto(a, b"XYZ"): ADDR_MATCH_WRITE, WRITE_REQ (one per FIFO batch), END_WRITE
  assert.equal(xfer({ addr: ADDR, write: [0x58, 0x59, 0x5a], gapNs: 1e6 }).ack, true);
  const written = py('e, d = events()\nprint(e, d)');
  const match = written.match(/^\[([\d, ]*)\] b'(.*)'$/);
  assert.ok(match, written);
  const w = match[1].split(',').map(Number);
  assert.equal(w[0], 2);
  assert.equal(w[w.length - 1], 32);
  assert.ok(w.slice(1, -1).every((f) => f === 8) && w.length >= 3, written);
  assert.equal(match[2], 'XYZ');
  // readfrom(a, 1): ADDR_MATCH_READ, READ_REQ, READ_REQ (the RX_DONE one), END_READ
  const r = xfer({ addr: ADDR, read: 1, gapNs: 1e6 });
  assert.deepEqual(r.data, [0x62]);
  assert.equal(py('print(events()[0])'), '[1, 4, 4, 16]');
  // write register + repeated START + read 2: END_WRITE at the repeated START, N+1 READ_REQ
  const rr = xfer({ addr: ADDR, write: [0x41], read: 2, gapNs: 1e6 });
  assert.equal(rr.data.length, 2);
  assert.equal(py('print(events())'), "([2, 8, 32, 1, 4, 4, 4, 16], b'A')");
  // scan (0-byte write): ADDR_MATCH_WRITE at STOP, END_WRITE
  assert.equal(xfer({ addr: ADDR, gapNs: 1e6 }).ack, true);
  assert.equal(py('print(events()[0])'), '[2, 32]');
  // another address: NAKed, no events
  assert.equal(xfer({ addr: ADDR + 1, write: [1], gapNs: 1e6 }).ack, false);
  assert.equal(py('print(events()[0])'), '[]');
  py('t.deinit()');
});

test('a slow hard READ_REQ handler holds SCL, and the meter counts its CPU time', { skip: skipNoBinaries }, () => {
  py(`t = I2CTarget(0, ${ADDR}, scl=machine.Pin(5), sda=machine.Pin(4))
t.irq(h, trigger=I2CTarget.IRQ_READ_REQ, hard=True)
slow[0] = 0`);
  const fast = xfer({ addr: ADDR, write: [1], read: 1, gapNs: 2e6 });
  py('slow[0] = 500');
  const slow = xfer({ addr: ADDR, write: [1], read: 1, gapNs: 2e6 });
  py('slow[0] = 0\nt.deinit()');
  // One READ_REQ gates the byte (the RX_DONE one comes after it): 500 us more SCL held.
  const extraHeld = slow.heldNs - fast.heldNs;
  assert.ok(extraHeld > 495e3 && extraHeld < 560e3, `held ${fast.heldNs} -> ${slow.heldNs}`);
  // Both READ_REQ handlers sleep: about 1000 us more IRQ time.
  const extraIrq = slow.irqNs - fast.irqNs;
  assert.ok(extraIrq > 990e3 && extraIrq < 1100e3, `irq ${fast.irqNs} -> ${slow.irqNs}`);
  assert.equal(slow.totalNs - slow.heldNs, slow.wireNs, 'the rest of the transaction is wire time');
});

test('mem mode: address pointer, auto-increment, wrap, prefetch, END_WRITE only for data', { skip: skipNoBinaries }, () => {
  py(`mem = bytearray(b"01234567")
n[0] = 0
def m(t):
    ev[n[0]] = t.irq().flags(); n[0] += 1
t = I2CTarget(0, ${ADDR}, mem=mem, scl=machine.Pin(5), sda=machine.Pin(4))
t.irq(m)`);
  const text = (bytes) => String.fromCharCode(...bytes);
  // writeto_mem(a, 6, b"test") wraps
  xfer({ addr: ADDR, write: [6, ...Buffer.from('test')], gapNs: 1e6 });
  assert.equal(py('print(bytes(mem), t.memaddr)'), "b'st2345te' 6");
  py('mem[:] = b"01234567"');
  // readfrom_mem(a, 0, 12) wraps
  assert.equal(text(xfer({ addr: ADDR, write: [0], read: 12, gapNs: 1e6 }).data), '012345670123');
  // write the address only, then plain reads: "2345", then "7012" (the prefetch skips 6)
  xfer({ addr: ADDR, write: [2], gapNs: 1e6 });
  assert.equal(text(xfer({ addr: ADDR, read: 4, gapNs: 1e6 }).data), '2345');
  assert.equal(text(xfer({ addr: ADDR, read: 4, gapNs: 1e6 }).data), '7012');
  // soft END_READ/END_WRITE: only END_READ for reads and the address-only write, END_WRITE for data
  assert.equal(py('print(events()[0])'), '[32, 16, 16, 16]');
  const held = xfer({ addr: ADDR, write: [0], read: 8, gapNs: 1e6 });
  py('t.deinit()');
  assert.equal(text(held.data), '01234567');
  assert.ok(held.heldNs > 0, 'each byte waits for its RD_REQ interrupt');
});

test('mem mode: an interrupt held off at the end of a write shifts the read (rp2 handles the repeated START first)', { skip: skipNoBinaries }, () => {
  // The joint's v2 layout: 7 bytes written from offset 0, the read continuing at 7. `hold`
  // disables interrupts from timer time t1 to t2 (us), polling TIMERAWL in viper (<1 us a turn).
  py(`import micropython
mem = bytearray(range(15))
t = I2CTarget(0, ${ADDR}, mem=mem, mem_addrsize=0, scl=machine.Pin(5), sda=machine.Pin(4))
@micropython.viper
def hold(t1: int, t2: int):
    timer = ptr32(0x40054028)
    while timer[0] - t1 < 0:
        pass
    s = machine.disable_irq()
    while timer[0] - t2 < 0:
        pass
    machine.enable_irq(s)`);
  const write = [0xa0, 0xa1, 0xa2, 0xa3, 0xa4, 0xa5, 0xa6];
  assert.deepEqual(xfer({ addr: ADDR, write, read: 8, gapNs: 1e6 }).data, [7, 8, 9, 10, 11, 12, 13, 14]);
  py('mem[:] = bytes(range(15))');
  // START 100 ms from now. At 400 kHz the 6th byte reaches the RX FIFO 157.5 us after it (and is
  // taken at once), the 7th at 180 us, the repeated START follows its ACK bit at 182.5 us.
  // Interrupts off from 170 us to 400 us: only the 7th byte is late.
  const startUs = Math.round(board.nanos / 1000) + 100_000;
  let result = null;
  bus.controller.transfer({ addr: ADDR, write, read: 8, atNs: startUs * 1000 }, (r) => (result = r));
  py(`hold(${startUs + 170}, ${startUs + 400})`);
  assert.ok(world.runUntilTrue(() => result, 1e9));
  // START_DET (of the repeated START) is handled before RX_FULL: the write ends with 6 bytes,
  // the 7th starts a new write at offset 0, and the read continues after it, at offset 1.
  assert.deepEqual(result.data, [0xa1, 0xa2, 0xa3, 0xa4, 0xa5, 6, 7, 8]);
  assert.equal(py('print(bytes(mem[:8]).hex())'), 'a6a1a2a3a4a50607');
  py('t.deinit()');
});
