// MicroPython's raw REPL over a board's USB CDC, in emulated time (for the device-fake tests).
import { usbText } from './helpers.mjs';

export class RawRepl {
  constructor(world, board) {
    this.world = world;
    this.board = board;
    this.usb = usbText(board);
  }

  /** Waits for USB and the REPL, then enters the raw REPL. */
  start(limitNanos = 3e9) {
    const { world, board, usb } = this;
    if (!world.runUntilTrue(() => board.usbConnected, limitNanos)) throw new Error('USB did not enumerate');
    board.usbWrite(Buffer.from('\r\x03\x03\x01'));
    if (!world.runUntilTrue(() => usb.text.includes('raw REPL; CTRL-B to exit\r\n>'), limitNanos)) {
      throw new Error(`no raw REPL: ${JSON.stringify(usb.text)}`);
    }
    return this;
  }

  /** Runs `code`; returns its stdout, throws with its traceback. */
  exec(code, limitNanos = 5e9) {
    const { world, board, usb } = this;
    usb.text = '';
    board.usbWrite(Buffer.from(code + '\x04'));
    const done = () => /OK[^]*\x04[^]*\x04>$/.test(usb.text);
    if (!world.runUntilTrue(done, limitNanos)) throw new Error(`timed out: ${JSON.stringify(usb.text)}`);
    const [out, err] = usb.text.slice(2, -2).split('\x04');
    if (err) throw new Error(err);
    return out;
  }
}
