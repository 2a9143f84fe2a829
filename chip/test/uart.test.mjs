// The PL011 fix on the register level (RP2040 datasheet 4.2; PL011 TRM 2.8, 3.3): a real transmit
// FIFO drained at the baud rate, and a transmit interrupt raised by the FIFO level falling through
// the trigger level and cleared by TXIC or by filling the FIFO above it. Then through MicroPython.
import assert from 'node:assert/strict';
import { describe, test } from 'node:test';
import { RP2040 } from 'rp2040js';
import { installPL011 } from '../src/uart.mjs';
import { bootToRepl, skipNoBinaries } from './helpers.mjs';

const UART1 = 0x40038000;
const DR = 0x00, FR = 0x18, IBRD = 0x24, FBRD = 0x28, LCR_H = 0x2c, CR = 0x30, IFLS = 0x34;
const IMSC = 0x38, RIS = 0x3c, MIS = 0x40, ICR = 0x44;
const TXFE = 1 << 7, TXFF = 1 << 5, BUSY = 1 << 3, TXRIS = 1 << 5;
const UART1_IRQ = 21;
// 115200 baud from clk_peri 125 MHz: divisor 67 + 52/64, the pico-sdk's rounding.
const CHAR_NS = (10 * 16 * (67 + 52 / 64) * 1e9) / 125e6;

function uart1({ stock = false } = {}) {
  const mcu = new RP2040();
  if (!stock) installPL011(mcu);
  const sent = [];
  mcu.uart[1].onByte = (value) => sent.push({ value, nanos: mcu.clock.nanos });
  const reg = (offset, value) => (value === undefined
    ? mcu.readUint32(UART1 + offset) : mcu.writeUint32(UART1 + offset, value));
  reg(IBRD, 67);
  reg(FBRD, 52);
  reg(LCR_H, (3 << 5) | (1 << 4)); // 8 data bits, FIFOs enabled
  reg(IFLS, 0); // TX trigger at 1/8 full (4 entries), as MicroPython's driver sets it
  reg(CR, (1 << 9) | (1 << 8) | 1);
  reg(IMSC, 1 << 5); // TXIM
  const irq = () => !!(mcu.core.pendingInterrupts & (1 << UART1_IRQ));
  return { mcu, reg, sent, irq, tick: (ns) => mcu.clock.tick(ns) };
}

describe('PL011 transmit path, register level', () => {
  test('an enabled UART with an empty FIFO raises no transmit interrupt', () => {
    const { reg, irq } = uart1();
    assert.equal(reg(RIS) & TXRIS, 0);
    assert.equal(irq(), false);
    assert.equal(reg(FR) & (TXFE | BUSY | TXFF), TXFE);
  });

  test('bytes leave in order, one character time (10 bits at 115200) apart', () => {
    const { reg, sent, tick } = uart1();
    for (const b of [0x05, 0x50, 0x00, 0xaa]) reg(DR, b);
    assert.ok(reg(FR) & BUSY);
    tick(4 * CHAR_NS + 1);
    assert.deepEqual(sent.map((s) => s.value), [0x05, 0x50, 0x00, 0xaa]);
    sent.forEach((s, i) => assert.ok(Math.abs(s.nanos - (i + 1) * CHAR_NS) < 1, `byte ${i} at ${s.nanos}`));
    assert.equal(reg(FR) & (TXFE | BUSY), TXFE);
  });

  test('TXRIS rises when the FIFO level falls to the trigger level, not before', () => {
    const { reg, tick, irq } = uart1();
    for (let i = 0; i < 8; i++) reg(DR, i); // the first goes to the shift register: 7 queued
    tick(2 * CHAR_NS + 1); // 5 queued: above the trigger
    assert.equal(reg(RIS) & TXRIS, 0);
    assert.equal(irq(), false);
    tick(CHAR_NS); // the shift register takes the next one: 4 queued
    assert.equal(reg(RIS) & TXRIS, TXRIS);
    assert.equal(reg(MIS) & TXRIS, TXRIS);
    assert.equal(irq(), true);
  });

  test('TXIC clears it for good: status reads do not raise it again', () => {
    const { reg, tick, irq } = uart1();
    for (let i = 0; i < 8; i++) reg(DR, i);
    tick(3 * CHAR_NS + 1);
    reg(ICR, TXRIS);
    for (const offset of [FR, RIS, MIS, DR]) reg(offset);
    assert.equal(reg(RIS) & TXRIS, 0);
    assert.equal(irq(), false);
    tick(10 * CHAR_NS); // the FIFO drains to empty without passing the trigger level again
    assert.equal(reg(RIS) & TXRIS, 0);
  });

  test('writing the FIFO above the trigger level clears it', () => {
    const { reg, tick, irq } = uart1();
    for (let i = 0; i < 8; i++) reg(DR, i);
    tick(3 * CHAR_NS + 1); // 4 queued, TXRIS set
    reg(DR, 8);
    assert.equal(reg(RIS) & TXRIS, 0);
    assert.equal(irq(), false);
  });

  test('32 entries fill the FIFO (TXFF); a write to a full FIFO is lost', () => {
    const { reg, sent, tick } = uart1();
    for (let i = 0; i < 34; i++) reg(DR, i); // 1 in the shift register, 32 queued, 1 lost
    assert.ok(reg(FR) & TXFF);
    tick(40 * CHAR_NS);
    assert.equal(sent.length, 33);
    assert.equal(sent.at(-1).value, 32);
  });

  test('rp2040js alone sets TXRIS again after TXIC (the deviation this fixes)', () => {
    const { reg } = uart1({ stock: true });
    reg(DR, 1);
    reg(ICR, TXRIS);
    assert.equal(reg(RIS) & TXRIS, TXRIS);
  });
});

function replWithUart(options) {
  const { board, world, usb } = bootToRepl(options);
  usb.text = '';
  const sent = [];
  board.rp2040.uart[1].onByte = (value) => sent.push(value);
  return { board, world, usb, sent };
}

describe('machine.UART on the emulated Pico', { skip: skipNoBinaries }, () => {
  test('UART(1, 115200).write returns and every byte reaches the TX side in order', () => {
    const { board, world, usb, sent } = replWithUart();
    // 100 bytes: more than the FIFO holds, so the driver's TX interrupt must refill it.
    board.usbWrite(Buffer.from('u=__import__("machine").UART(1,115200);print(u.write(b"x"),'
      + 'u.write(bytes(range(100))));u.flush();print("sent")\r'));
    assert.ok(world.runUntilTrue(() => usb.text.endsWith('>>> '), 500e6), usb.text);
    assert.match(usb.text, /\r\n1 100\r\nsent\r\n/);
    assert.deepEqual(sent, [0x78, ...Array.from({ length: 100 }, (_, i) => i)]);
  });

  test('with rp2040js\'s own UART the same write never returns', () => {
    const { board, world, usb } = replWithUart({ stockUart: true });
    board.usbWrite(Buffer.from('u=__import__("machine").UART(1,115200);u.write(b"x");print("back")\r'));
    assert.equal(world.runUntilTrue(() => usb.text.includes('back\r\n'), 100e6), false);
  });
});
