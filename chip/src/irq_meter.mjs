// CPU time spent in one exception handler, observed at rp2040js's exception entry and return.
//
// The core's exceptionEntry(n) and exceptionReturn() are wrapped (once per core, shared by every
// meter on it). Time is charged to whichever exception is on top of the active stack, so time in a
// handler that preempts the measured one (a higher-priority USB or timer IRQ) is not counted.
// rp2040js does not model exception entry/return cycles (12+ on the M0+) or tail-chaining:
// every figure is the handler's own instructions, a lower bound.

const I2C0_IRQ = 23;

function tracker(mcu) {
  const { core } = mcu;
  if (core.__irqTracker) return core.__irqTracker;
  const t = { stack: [], last: 0, meters: [] };
  const charge = () => {
    const now = mcu.clock.nanos;
    const top = t.stack[t.stack.length - 1];
    if (top !== undefined) {
      for (const m of t.meters) if (m.exception === top) m.totalNs_ += now - t.last;
    }
    t.last = now;
  };
  const entry = core.exceptionEntry.bind(core);
  core.exceptionEntry = (n) => {
    charge();
    t.stack.push(n);
    for (const m of t.meters) if (m.exception === n) m.entries++;
    entry(n);
  };
  const ret = core.exceptionReturn.bind(core);
  core.exceptionReturn = (excReturn) => {
    charge();
    t.stack.pop();
    ret(excReturn);
  };
  t.charge = charge;
  core.__irqTracker = t;
  return t;
}

export class IrqMeter {
  /** Measure the handler of hardware IRQ `irq` (I2C0 = 23, I2C1 = 24) on `mcu`. */
  constructor(mcu, irq = I2C0_IRQ) {
    this.mcu = mcu;
    this.irq = irq;
    this.exception = 16 + irq;
    this.totalNs_ = 0;
    this.entries = 0;
    this.t = tracker(mcu);
    this.t.meters.push(this);
  }

  /** Total handler time so far, in ns, including the running handler up to now. */
  get totalNs() {
    this.t.charge();
    return this.totalNs_;
  }

  /** Neither running nor pending. */
  get idle() {
    const { core } = this.mcu;
    return !this.t.stack.includes(this.exception) && !(core.pendingInterrupts & (1 << this.irq));
  }
}
