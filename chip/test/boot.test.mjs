// The stock MicroPython UF2 boots on the bootrom to its REPL and runs Python typed over USB.
import assert from 'node:assert/strict';
import { test } from 'node:test';
import { Board, World } from '../src/board.mjs';
import { skipNoBinaries, usbText } from './helpers.mjs';

test('boots to the REPL and evaluates over USB CDC', { skip: skipNoBinaries }, () => {
  const board = new Board();
  const world = new World();
  world.add(board);
  const usb = usbText(board);
  assert.ok(world.runUntilTrue(() => board.usbConnected, 2e9), 'USB enumerated');
  board.usbWrite(Buffer.from('\r'));
  assert.ok(world.runUntilTrue(() => usb.text.includes('>>> '), 1e9), usb.text);
  assert.match(usb.text, /MicroPython v1\.28\.0/);
  usb.text = '';
  board.usbWrite(Buffer.from('print(6*7, __import__("machine").freq())\r'));
  assert.ok(world.runUntilTrue(() => usb.text.endsWith('>>> '), 1e9), usb.text);
  assert.match(usb.text, /\r\n42 125000000\r\n/);
});
