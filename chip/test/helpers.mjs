// Shared by the node tests: skip when the emulated Pico's binaries are missing.
import { existsSync } from 'node:fs';
import { DEFAULT_BOOTROM, DEFAULT_UF2 } from '../src/board.mjs';

export const missingBinaries = [DEFAULT_UF2, DEFAULT_BOOTROM].filter((p) => !existsSync(p));
export const skipNoBinaries = missingBinaries.length
  ? `missing ${missingBinaries.join(', ')} (see ../shared/rp2040/README.md)` : false;

/** Collects a board's USB output as text. */
export function usbText(board) {
  const state = { text: '' };
  board.onUsb((buffer) => { state.text += Buffer.from(buffer).toString('latin1'); });
  return state;
}
