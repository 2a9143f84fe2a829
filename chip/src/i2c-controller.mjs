// An I2C bus behind one of the board's DW_apb_i2c blocks in controller mode, taking bus time.
//
// rp2040js 1.4.1 completes every controller transfer at once (its onStart/onConnect/onWriteByte/
// onReadByte/onStop hooks answer synchronously), so I2C costs the firmware no time at all. Here each
// phase completes after its time on the wire at the programmed SCL timing (RP2040 datasheet 4.3,
// DW_apb_i2c): one SCL period is (HCNT + SPKLEN + 7) high plus (LCNT + 1) low ic_clk (= clk_sys)
// cycles, from IC_SS_* or IC_FS_* by IC_CON.SPEED. Phases: START or repeated START 1 period, the
// address byte 9 (with the ACK bit), each data byte 9, STOP 1. With IC_CON.TX_EMPTY_CTRL set (as
// the pico-sdk sets it) TX_EMPTY is raised only when the byte from the shift register has gone out
// and the FIFO is at or below IC_TX_TL, as the silicon does, instead of when the command is popped.
// Targets (addresses 7-bit) implement: start(read) -> ack, write(byte) -> ack, read() -> byte,
// stop(). An address no target claims is NACKed (ABRT_7B_ADDR_NOACK).
// The bus's pull-ups hold the `pullups` pins high (rp2040js models no pad pulls on inputs).
// MicroPython's rp2 port bit-bangs zero-length writes on the GPIOs (I2C.scan(), and the STOP it
// sends after a failed register-address write): with the pull-ups those finish at once instead of
// waiting out the clock-stretch timeout, but the targets here do not see them (scan() finds
// nothing). Not modelled: clock
// stretching by targets, arbitration, SDA hold/setup times, rise times (a real bus is a little slower).

const IC_FS_SPKLEN = 0xa0;
const TX_EMPTY_CTRL = 1 << 8;
const R_TX_EMPTY = 1 << 4;
const SPEED_STANDARD = 1;

export class TimedI2CController {
  constructor(board, index, { pullups = [] } = {}) {
    this.board = board;
    for (const pin of pullups) board.rp2040.gpio[pin].setInputValue(true);
    const i2c = board.rp2040.i2c[index];
    this.i2c = i2c;
    this.targets = new Map();
    this.spikelen = 7; // ic_fs_spklen reset value
    this.current = null; // the target addressed by the transfer in progress
    this.transactions = 0;
    this.busyNanos = 0; // total time the bus was driven
    const write = i2c.writeUint32.bind(i2c);
    i2c.writeUint32 = (offset, value) => {
      // rp2040js drops odd SPKLEN values; keep our own copy (the field is 8 bits, minimum 1).
      if (offset === IC_FS_SPKLEN) this.spikelen = Math.max(1, value & 0xff);
      write(offset, value);
    };
    const setInterrupts = i2c.setInterrupts.bind(i2c);
    const nextCommand = i2c.nextCommand.bind(i2c);
    let popping = false;
    this.raise = setInterrupts;
    i2c.setInterrupts = (mask) => {
      const m = popping && i2c.control & TX_EMPTY_CTRL ? mask & ~R_TX_EMPTY : mask;
      if (m) setInterrupts(m);
    };
    i2c.nextCommand = () => {
      popping = true;
      try {
        nextCommand();
      } finally {
        popping = false;
      }
    };
    i2c.onStart = () => this.phase(1, () => i2c.completeStart());
    i2c.onConnect = (address, mode) => {
      this.current = this.targets.get(address & 0x7f) ?? null;
      this.phase(9, () => {
        const ack = this.current ? !!this.current.start(mode === 1) : false;
        if (!ack) this.current = null;
        i2c.completeConnect(ack);
      });
    };
    i2c.onWriteByte = (value) => this.phase(9, () => {
      const ack = this.current ? !!this.current.write(value & 0xff) : false;
      i2c.completeWrite(ack);
    });
    i2c.onReadByte = () => {
      const value = this.current ? this.current.read() & 0xff : 0xff;
      this.phase(9, () => i2c.completeRead(value));
    };
    i2c.onStop = () => this.phase(1, () => {
      this.current?.stop();
      this.current = null;
      this.transactions++;
      i2c.completeStop();
    });
  }

  /** Puts `target` on the bus at 7-bit `address`. */
  attach(address, target) {
    this.targets.set(address, target);
    return target;
  }

  /** One SCL period in ic_clk cycles at the programmed speed. */
  get periodCycles() {
    const i2c = this.i2c;
    const standard = i2c.speed === SPEED_STANDARD;
    const hcnt = standard ? i2c.ssClockHighPeriod : i2c.fsClockHighPeriod;
    const lcnt = standard ? i2c.ssClockLowPeriod : i2c.fsClockLowPeriod;
    return hcnt + this.spikelen + 7 + lcnt + 1;
  }

  /** SCL frequency in Hz. */
  get sclHz() {
    return this.board.rp2040.clkSys / this.periodCycles;
  }

  phase(periods, complete) {
    const nanos = periods * this.periodCycles * this.board.cycleNanos;
    this.busyNanos += nanos;
    this.board.afterNanos(nanos, () => {
      const i2c = this.i2c;
      // The byte has left the shift register: TX_EMPTY if nothing else waits to go.
      if (i2c.txFIFO.itemCount <= i2c.txThreshold) this.raise(R_TX_EMPTY);
      complete();
      if (i2c.txFIFO.itemCount <= i2c.txThreshold && !i2c.busy) this.raise(R_TX_EMPTY);
    });
  }
}
