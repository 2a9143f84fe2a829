// CircuitPython 10.2.1 on the emulated Pico: what it needs beyond MicroPython (the BOOTSEL sense
// line, the composite USB device); the CIRCUITPY FAT image is tested from Python
// (tests/chip/test_chip_circuitpython.py), where the image is built.
import assert from 'node:assert/strict';
import { existsSync } from 'node:fs';
import { test } from 'node:test';
import { Board, QSPI_SS, RUNTIMES, World } from '../src/board.mjs';
import { skipNoBinaries, usbText } from './helpers.mjs';

const SIO_GPIO_HI_IN = 0xd0000008;
const skip = skipNoBinaries || (existsSync(RUNTIMES.circuitpython.uf2) ? false
  : `missing ${RUNTIMES.circuitpython.uf2} (see ../shared/rp2040/README.md)`);

test('BOOTSEL released: the QSPI chip select reads 1 in GPIO_HI_IN (rp2040js reads 0)', { skip }, () => {
  assert.equal((new Board().rp2040.readUint32(SIO_GPIO_HI_IN) >> QSPI_SS) & 1, 1);
  assert.equal((new Board({ stockQspi: true }).rp2040.readUint32(SIO_GPIO_HI_IN) >> QSPI_SS) & 1, 0);
});

/** USB descriptors: the interface classes in the configuration descriptor. */
function interfaceClasses(descriptors) {
  const classes = [];
  for (let at = 0; at + 1 < descriptors.length && descriptors[at] >= 2; at += descriptors[at]) {
    if (descriptors[at + 1] === 4) classes.push(descriptors[at + 5]); // INTERFACE: bInterfaceClass
  }
  return classes;
}

test('CircuitPython boots to its REPL over the CDC of its composite USB device', { skip }, () => {
  const board = new Board({ runtime: 'circuitpython' });
  const world = new World();
  world.add(board);
  const usb = usbText(board);
  assert.ok(world.runUntilTrue(() => board.usbConnected, 3e9), 'USB configured');
  // CDC control + data, mass storage (CIRCUITPY), HID, MIDI (audio control + streaming)
  assert.deepEqual(interfaceClasses(board.cdc.descriptors), [2, 10, 8, 3, 1, 1]);
  assert.ok(board.cdc.inEndpoint > 0 && board.cdc.outEndpoint > 0, 'the CDC data endpoints');
  // Output before the host sets DTR is lost: ask for the REPL until it answers.
  for (let tries = 0; !usb.text.includes('>>> ') && tries < 10; tries += 1) {
    board.usbWrite(Buffer.from('\r'));
    world.runUntilTrue(() => usb.text.includes('>>> '), 0.3e9);
  }
  assert.match(usb.text, /Adafruit CircuitPython 10\.2\.1[^]*>>> /);
  world.runFor(0.1e9);
  usb.text = '';
  board.usbWrite(Buffer.from('import microcontroller; print(6*7, microcontroller.cpu.frequency)\r'));
  assert.ok(world.runUntilTrue(() => /\r\n42 125000000\r\n>>> /.test(usb.text), 1e9), usb.text);
});
