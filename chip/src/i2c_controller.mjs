// An I2C bus controller, bit-timed on an emulated board's clock, that honours clock stretching.
//
// One transaction writes `write` bytes after the address, then (repeated START) reads `read`
// bytes, then STOP; with no read it is a plain write, with `read` and no `write` a plain read.
// Nominal wire time in bit times (design.md): START 1, every byte 9 (8 bits + ACK), repeated
// START 1, STOP 1:  1 + 9(1+w) + (r > 0 ? 1 + 9(1+r) : 0) + 1.
// Whenever a target holds SCL low the controller's time stops; the held time is measured per
// transaction, as is the whole transaction (START to the end of STOP).
//
// Targets implement the bus side of RP2040I2C: busStart(repeated), busAddress(addr, read) -> ack,
// busWriteByte(byte, resume) -> ack | null (held), busReadByte(resume) -> byte | null (held),
// busReadAck(ack), busStop().

export function wireBits(write, read) {
  if (read > 0 && write === 0) return 1 + 9 * (1 + read) + 1;
  return 1 + 9 * (1 + write) + (read > 0 ? 1 + 9 * (1 + read) : 0) + 1;
}

export class I2CController {
  /**
   * @param clock an rp2040js SimulationClock (the target board's), in nanoseconds
   * @param khz bus clock in kHz (100, 400, 1000)
   */
  constructor(clock, { khz = 400, stretchTimeoutNs = 35e6 } = {}) {
    this.clock = clock;
    this.khz = khz;
    // How long a target may hold SCL before the controller gives up on the transaction (SMBus
    // tTIMEOUT max 35 ms). A target that still holds SCL keeps the bus busy: later transactions
    // wait for it, up to the same limit each, and fail with timedOut.
    this.stretchTimeoutNs = stretchTimeoutNs;
    this.targets = [];
    this.queue = [];
    this.current = null;
    this.irqMeters = [];
  }

  get bitNs() {
    return 1e6 / this.khz;
  }

  attach(target) {
    this.targets.push(target);
    return this;
  }

  /** Count IRQ CPU time of `meter` (an IrqMeter) into each transaction's result. */
  meterIrq(meter) {
    this.irqMeters.push(meter);
    return this;
  }

  /**
   * Queue a transaction; `done(result)` gets { addr, write, read, ack, timedOut, data, startNs,
   * endNs, totalNs, heldNs, wireNs, bits, irqNs }. ack is false when the address or a written byte
   * was NAKed (the controller then sends STOP) or SCL was held past stretchTimeoutNs (timedOut). Transactions run in order, each starting once the
   * previous one has ended and `gapNs` more have passed, and not before emulated time `atNs`.
   */
  transfer({ addr, write = [], read = 0, gapNs = 0, atNs = 0 }, done) {
    this.queue.push({ addr, write: Array.from(write), read, gapNs, atNs, done });
    if (!this.current) this.next();
  }

  /** The same as a Promise. */
  run(spec) {
    return new Promise((resolve) => this.transfer(spec, resolve));
  }

  next() {
    const job = this.queue.shift();
    if (!job) {
      this.current = null;
      return;
    }
    this.current = job;
    this.after(Math.max(job.gapNs, job.atNs - this.clock.nanos), () => this.begin(job));
  }

  after(ns, fn) {
    const alarm = this.clock.createAlarm(fn);
    alarm.schedule(Math.max(0, ns));
  }

  bits(n, fn) {
    this.after(n * this.bitNs, fn);
  }

  /**
   * step(resume) returns a value, or null while the target holds SCL (it calls resume(value)
   * when it lets go); fn(value) continues the transaction either way, the hold counted.
   */
  stretch(step, fn) {
    const job = this.current;
    const since = this.clock.nanos;
    let settled = false;
    const resume = (value) => {
      if (settled) return;
      settled = true;
      job.heldNs += this.clock.nanos - since;
      // Continue from the alarm list, not from inside the CPU's register access.
      this.after(0, () => fn(value));
    };
    const result = step(resume);
    if (result !== null) {
      settled = true;
      fn(result);
      return;
    }
    this.after(this.stretchTimeoutNs, () => {
      if (settled) return;
      settled = true;
      job.heldNs += this.clock.nanos - since;
      job.timedOut = true;
      job.ack = false;
      this.stop(job);
    });
  }

  get sclHeld() {
    return this.targets.some((t) => t.holdingScl);
  }

  begin(job) {
    job.startNs = this.clock.nanos;
    job.heldNs = 0;
    job.ack = true;
    job.timedOut = false;
    job.data = [];
    job.irqStart = this.irqMeters.map((m) => m.totalNs);
    this.target = null;
    if (this.sclHeld) {
      // A target still holds SCL from an earlier transaction: the bus is busy until it lets go.
      job.waitedNs = (job.waitedNs ?? 0) + 10_000;
      if (job.waitedNs > this.stretchTimeoutNs) {
        job.heldNs = job.waitedNs;
        job.timedOut = true;
        job.ack = false;
        this.finish(job);
      } else {
        this.after(10_000, () => this.begin(job));
      }
      return;
    }
    const writing = job.write.length > 0 || job.read === 0;
    for (const t of this.targets) t.busStart(false);
    this.bits(1, () => (writing ? this.address(job, false) : this.address(job, true)));
  }

  address(job, read) {
    this.bits(8, () => {
      this.target = null;
      for (const t of this.targets) {
        if (t.busAddress(job.addr, read) && !this.target) this.target = t;
      }
      this.bits(1, () => {
        if (!this.target) {
          job.ack = false;
          this.stop(job);
        } else if (read) {
          this.readByte(job, 0);
        } else {
          this.writeByte(job, 0);
        }
      });
    });
  }

  writeByte(job, index) {
    if (index >= job.write.length) {
      if (job.read > 0) {
        for (const t of this.targets) t.busStart(true);
        this.bits(1, () => this.address(job, true));
      } else {
        this.stop(job);
      }
      return;
    }
    this.bits(8, () => {
      this.stretch(
        (resume) => this.target.busWriteByte(job.write[index], resume),
        (ack) => {
          this.bits(1, () => {
            if (!ack) {
              job.ack = false;
              this.stop(job);
            } else {
              this.writeByte(job, index + 1);
            }
          });
        },
      );
    });
  }

  readByte(job, index) {
    this.stretch(
      (resume) => this.target.busReadByte(resume),
      (byte) => {
        this.bits(9, () => {
          job.data.push(byte);
          const last = index === job.read - 1;
          this.target.busReadAck(!last);
          if (last) this.stop(job);
          else this.readByte(job, index + 1);
        });
      },
    );
  }

  stop(job) {
    this.bits(1, () => {
      for (const t of this.targets) t.busStop();
      this.finish(job);
    });
  }

  finish(job) {
    job.endNs = this.clock.nanos;
    job.totalNs = job.endNs - job.startNs;
    job.bits = wireBits(job.write.length, job.read);
    job.wireNs = job.bits * this.bitNs;
    this.finishIrq(job);
    this.next();
  }

  /**
   * The IRQ CPU time of a transaction: from its START until the target's I2C interrupt is idle
   * after STOP, or until the next transaction starts, whichever is first.
   */
  finishIrq(job) {
    const meters = this.irqMeters;
    const report = () => {
      job.irqNs = meters.length ? meters.reduce((s, m, i) => s + m.totalNs - job.irqStart[i], 0) : null;
      const { done } = job;
      if (done) done(resultOf(job));
    };
    if (!meters.length) {
      report();
      return;
    }
    const limitNs = this.clock.nanos + 50e6;
    const poll = () => {
      const nextStarted = this.current !== job && this.current && this.current.startNs !== undefined;
      if (meters.every((m) => m.idle) || nextStarted || this.clock.nanos > limitNs) report();
      else this.after(1000, poll);
    };
    this.after(0, poll);
  }
}

function resultOf(job) {
  return {
    addr: job.addr,
    write: job.write,
    read: job.read,
    ack: job.ack,
    timedOut: job.timedOut,
    data: job.data,
    startNs: job.startNs,
    endNs: job.endNs,
    totalNs: job.totalNs,
    heldNs: job.heldNs,
    wireNs: job.wireNs,
    bits: job.bits,
    irqNs: job.irqNs,
  };
}
