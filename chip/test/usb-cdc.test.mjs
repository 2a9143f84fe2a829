// The USB host fix: OUT transfers are NAKed (the armed buffer stays armed, no interrupt) until
// the host has data, as a real host does (USB 2.0 8.5.2; RP2040 datasheet 4.1.2.5: the device sees
// BUFF_STATUS only when a buffer completes). Register level first, then the idle MicroPython REPL.
import assert from 'node:assert/strict';
import { describe, test } from 'node:test';
import { RP2040, USBCDC } from 'rp2040js';
import { HostCDC } from '../src/usb-cdc.mjs';
import { bootToRepl, skipNoBinaries } from './helpers.mjs';

const DPRAM = 0x50100000;
const USB = 0x50110000;
const BUFF_STATUS = 0x58, INTR = 0x8c;
const EP1_OUT_CONTROL = 0x0c, EP1_OUT_BUFFER_CONTROL = 0x8c;
const BUFFER = 0x180;
const AVAILABLE = 1 << 10, FULL = 1 << 15, LEN = 0x3ff;
const EP1_OUT_DONE = 1 << 3, INTR_BUFF_STATUS = 1 << 4;

function device(CDC) {
  const mcu = new RP2040();
  const cdc = new CDC(mcu.usbCtrl);
  cdc.outEndpoint = 1; // what enumeration finds in MicroPython's descriptors
  mcu.writeUint32(DPRAM + EP1_OUT_CONTROL, (1 << 31) | (1 << 29) | BUFFER); // enabled, IRQ per buffer
  const arm = () => mcu.writeUint32(DPRAM + EP1_OUT_BUFFER_CONTROL, AVAILABLE | 64);
  const bufferControl = () => mcu.readUint32(DPRAM + EP1_OUT_BUFFER_CONTROL);
  const done = () => !!(mcu.readUint32(USB + BUFF_STATUS) & EP1_OUT_DONE);
  const clear = () => mcu.writeUint32(USB + BUFF_STATUS, EP1_OUT_DONE);
  const data = (n) => Array.from(mcu.usbDPRAM.subarray(BUFFER, BUFFER + n));
  return { mcu, cdc, arm, bufferControl, done, clear, data, tick: (ns) => mcu.clock.tick(ns) };
}

describe('USB CDC OUT endpoint, register level', () => {
  test('an armed OUT buffer stays armed while the host has nothing to send', () => {
    const { mcu, arm, bufferControl, done, tick } = device(HostCDC);
    arm();
    tick(10e6);
    assert.equal(done(), false);
    assert.equal(bufferControl() & FULL, 0);
    assert.equal(mcu.readUint32(USB + INTR) & INTR_BUFF_STATUS, 0);
  });

  test('bytes from the host complete it with exactly those bytes', () => {
    const { cdc, arm, bufferControl, done, data, tick } = device(HostCDC);
    arm();
    tick(1e6);
    cdc.sendSerialBytes([0x41, 0x42]);
    cdc.sendSerialBytes([0x43]);
    tick(20e3);
    assert.equal(done(), true);
    assert.equal(bufferControl() & FULL, FULL);
    assert.equal(bufferControl() & LEN, 3);
    assert.deepEqual(data(3), [0x41, 0x42, 0x43]);
  });

  test('more than a packet goes out in packets of the armed length, none lost', () => {
    const { cdc, arm, bufferControl, clear, data, tick } = device(HostCDC);
    const bytes = Array.from({ length: 1000 }, (_, i) => i & 0xff);
    cdc.sendSerialBytes(bytes);
    const received = [];
    while (received.length < bytes.length) {
      arm();
      tick(20e3);
      const n = bufferControl() & LEN;
      assert.equal(n, Math.min(64, bytes.length - received.length));
      received.push(...data(n));
      clear();
    }
    assert.deepEqual(received, bytes);
    arm();
    tick(1e6);
    assert.equal(bufferControl() & FULL, 0);
  });

  test('rp2040js alone completes it at once with zero bytes (the deviation this fixes)', () => {
    const { arm, bufferControl, done, tick } = device(USBCDC);
    arm();
    tick(20e3);
    assert.equal(done(), true);
    assert.equal(bufferControl() & (FULL | LEN), FULL);
  });
});

describe('USB CDC on the emulated Pico', { skip: skipNoBinaries }, () => {
  function idleOutTransfers(options) {
    const { board, world } = bootToRepl(options);
    let completions = 0;
    const finishRead = board.rp2040.usbCtrl.finishRead.bind(board.rp2040.usbCtrl);
    board.rp2040.usbCtrl.finishRead = (endpoint, buffer) => { completions += 1; finishRead(endpoint, buffer); };
    world.runFor(20e6);
    return completions;
  }

  test('the idle REPL takes no OUT completion (rp2040js alone: one every ~10 us)', () => {
    assert.equal(idleOutTransfers({}), 0);
    assert.ok(idleOutTransfers({ stockUsb: true }) > 500);
  });
});
