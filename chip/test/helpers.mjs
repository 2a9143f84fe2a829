// Shared by the node tests: skip when the emulated Pico's binaries are missing.
import { existsSync } from 'node:fs';
import assert from 'node:assert/strict';
import { Board, DEFAULT_BOOTROM, DEFAULT_UF2, World } from '../src/board.mjs';

export const missingBinaries = [DEFAULT_UF2, DEFAULT_BOOTROM].filter((p) => !existsSync(p));
export const skipNoBinaries = missingBinaries.length
  ? `missing ${missingBinaries.join(', ')} (see ../shared/rp2040/README.md)` : false;

/** Collects a board's USB output as text. */
export function usbText(board) {
  const state = { text: '' };
  board.onUsb((buffer) => { state.text += Buffer.from(buffer).toString('latin1'); });
  return state;
}

/** A board booted to MicroPython's REPL prompt in a world of its own; `usb` collects its output. */
export function bootToRepl(options) {
  const board = new Board(options);
  const world = new World();
  world.add(board);
  const usb = usbText(board);
  assert.ok(world.runUntilTrue(() => board.usbConnected, 2e9));
  board.usbWrite(Buffer.from('\r'));
  assert.ok(world.runUntilTrue(() => usb.text.includes('>>> '), 1e9));
  return { board, world, usb };
}
