// PIO state machines clocked by clk_sys through their CLKDIV, as the RP2040 datasheet (3.5.5) says.
//
// rp2040js 1.4.1 runs each PIO block off its own JavaScript timer (1000 instructions per event-loop
// turn, whatever the emulated time), steps every state machine whether it is enabled or not,
// ignores CLKDIV and executes one instruction per step, so delay cycles ([n]) take no time. Here
// the state machines are stepped lazily on the emulated clock instead:
//
// * an enabled machine gets one clock enable every CLKDIV = INT + FRAC/256 system cycles (INT 0
//   means 65536); with a fraction the enables are spaced floor/ceil so that the average is exact;
// * an instruction takes one enable plus its delay; a stalled instruction (WAIT, blocking
//   PULL/PUSH) re-tries every enable and its delay counts from the enable it completes on;
// * the machines catch up to the present before any PIO register is read or written, whenever
//   something outside asks (`sync()`, e.g. a device model sampling a pin), and at least every
//   `period_ns` while a machine runs, so FIFO levels, pins and interrupts are exact when the CPU
//   looks and late by at most that period otherwise;
// * pin changes are reported with the emulated time of the PIO cycle that made them (`nanos`).
//
// Known limits: inputs (WAIT pin, IN pins, JMP pin) are read at catch-up time, not at the PIO
// cycle; a CPU write that ends a stall takes effect at once instead of at the next enable
// (at most one PIO cycle early).

const CTRL = 0x000;
const SM0_CLKDIV = 0x0c8;
const SM_STRIDE = 0x18;
const JMP_X_DEC = 0b010;
const JMP_Y_DEC = 0b100;

// rp2040js WaitType values for stalls that only the CPU (or DMA) can end.
const WAIT_TX_FIFO = 4;
const WAIT_RX_FIFO = 3;
const WAIT_OUT = 5;

class MachineClock {
  constructor(sm) {
    this.sm = sm;
    this.div256 = 256; // CLKDIV in 1/256 system cycles
    this.base = 0; // system cycle the divider (re)started at
    this.k = 0; // enables since then
    this.next = 0; // system cycle of the next enable
    this.busy = 0; // enables still owed to delay cycles
    this.seen = 0; // sm.cycles after our last step
  }

  restart(cycle) {
    const { clockDivInt, clockDivFrac } = this.sm;
    this.div256 = (clockDivInt === 0 ? 65536 : clockDivInt) * 256 + clockDivFrac;
    this.base = cycle;
    this.k = 0;
    this.next = cycle + Math.floor(this.div256 / 256);
    this.busy = 0;
    this.seen = this.sm.cycles;
  }

  advance(n) {
    this.k += n;
    this.next = this.base + Math.floor(((this.k + 1) * this.div256) / 256);
  }

  /** System cycle of the n-th enable from now (n >= 1). */
  enableAt(n) {
    return this.base + Math.floor(((this.k + n) * this.div256) / 256);
  }
}

function stalledOnCpu(sm) {
  if (!sm.waiting) {
    return false;
  }
  const t = sm.waitType;
  if (t === WAIT_TX_FIFO || t === WAIT_OUT) {
    return sm.txFIFO.empty;
  }
  return t === WAIT_RX_FIFO && sm.rxFIFO.full;
}

export class PioClock {
  /**
   * @param mcu   the rp2040js RP2040
   * @param clock its clock (nanos, createAlarm)
   */
  constructor(mcu, clock, { periodNanos = 20000 } = {}) {
    this.mcu = mcu;
    this.clock = clock;
    this.periodNanos = periodNanos;
    this.cycle = -1; // system cycle of the PIO step running now (-1: not stepping)
    this.synced = 0; // system cycle the machines have caught up to
    this.busy = false;
    this.blocks = mcu.pio.map((pio) => this.adopt(pio));
    this.alarm = clock.createAlarm(() => this.tick());
  }

  get nsPerCycle() {
    return 1e9 / this.mcu.clkSys;
  }

  /** The present in system cycles. */
  nowCycle() {
    return this.cycle >= 0 ? this.cycle : Math.round(this.clock.nanos / this.nsPerCycle);
  }

  /** Emulated time in ns: inside a PIO step, the time of that PIO cycle. */
  get nanos() {
    return this.cycle >= 0 ? this.cycle * this.nsPerCycle : this.clock.nanos;
  }

  adopt(pio) {
    const block = { pio, clocks: pio.machines.map((sm) => new MachineClock(sm)) };
    pio.run = () => this.schedule(); // replaces the free-running JavaScript timer
    const read = pio.readUint32.bind(pio);
    const write = pio.writeUint32.bind(pio);
    pio.readUint32 = (offset) => {
      this.sync();
      return read(offset);
    };
    pio.writeUint32 = (offset, value) => {
      this.sync();
      const now = this.nowCycle();
      const was = pio.machines.map((sm) => sm.enabled);
      write(offset, value);
      if (offset === CTRL) {
        block.clocks.forEach((mc, i) => {
          const restart = value & (1 << (4 + i)) || value & (1 << (8 + i));
          if ((mc.sm.enabled && !was[i]) || restart) {
            mc.restart(now);
          }
        });
        this.schedule();
      } else if (offset >= SM0_CLKDIV && offset < SM0_CLKDIV + 4 * SM_STRIDE) {
        const i = Math.floor((offset - SM0_CLKDIV) / SM_STRIDE);
        if (offset === SM0_CLKDIV + i * SM_STRIDE) {
          block.clocks[i].restart(now);
        }
      }
    };
    return block;
  }

  running() {
    return this.blocks.some((b) => b.pio.machines.some((sm) => sm.enabled));
  }

  schedule() {
    if (!this.alarm.scheduled && this.running()) {
      this.alarm.schedule(this.periodNanos);
    }
  }

  tick() {
    this.alarm.scheduled = false;
    this.sync();
    this.schedule();
  }

  /** Step every enabled state machine up to the present. */
  sync() {
    if (this.busy) {
      return;
    }
    const target = Math.round(this.clock.nanos / this.nsPerCycle);
    if (target <= this.synced) {
      return;
    }
    this.busy = true;
    try {
      for (const block of this.blocks) {
        this.runBlock(block, target);
      }
    } finally {
      this.cycle = -1;
      this.busy = false;
    }
    this.synced = target;
  }

  runBlock(block, target) {
    const active = block.clocks.filter((mc) => mc.sm.enabled);
    if (active.length === 0) {
      return;
    }
    const alone = active.length === 1;
    for (;;) {
      let mc = active[0];
      for (let i = 1; i < active.length; i++) {
        if (active[i].next < mc.next) {
          mc = active[i];
        }
      }
      if (mc.next > target) {
        return;
      }
      this.cycle = mc.next;
      this.clockEnable(block, mc, target, alone);
    }
  }

  /** One enable of machine `mc`, or a run of enables that provably change nothing outside. */
  clockEnable(block, mc, target, alone) {
    const { sm } = mc;
    if (sm.cycles !== mc.seen) {
      mc.busy += Math.max(0, sm.cycles - mc.seen); // delay of a stall the CPU ended
      mc.seen = sm.cycles;
    }
    if (mc.busy > 0) {
      const n = Math.min(mc.busy, Math.max(1, this.enablesUntil(mc, target)));
      mc.busy -= n;
      mc.advance(n);
      return;
    }
    if (stalledOnCpu(sm)) {
      mc.advance(Math.max(1, this.enablesUntil(mc, target)));
      return;
    }
    const wasWaiting = sm.waiting;
    const pc = sm.pc;
    const before = sm.cycles;
    sm.step();
    const spent = sm.cycles - before;
    mc.seen = sm.cycles;
    mc.busy = wasWaiting ? spent : Math.max(0, spent - 1);
    mc.advance(1);
    block.pio.checkChangedPins();
    if (alone && !sm.waiting && sm.pc === pc) {
      this.skipSelfLoop(mc, target);
    }
  }

  /** `jmp x-- self` / `jmp y-- self`: the loop changes only the counter; run it in one go. */
  skipSelfLoop(mc, target) {
    const { sm } = mc;
    const op = sm.pio.instructions[sm.pc];
    if (op >>> 13 !== 0 || (op & 0x1f) !== sm.pc || sm.execValid) {
      return;
    }
    const cond = (op >> 5) & 7;
    if (cond !== JMP_X_DEC && cond !== JMP_Y_DEC) {
      return;
    }
    const reg = cond === JMP_X_DEC ? sm.x >>> 0 : sm.y >>> 0;
    if (reg === 0) {
      return;
    }
    const per = 1 + mc.busy; // an iteration: the delay owed now, then the jump again
    const n = Math.min(reg, Math.floor(this.enablesUntil(mc, target) / per));
    if (n <= 0) {
      return;
    }
    if (cond === JMP_X_DEC) {
      sm.x = (reg - n) >>> 0;
    } else {
      sm.y = (reg - n) >>> 0;
    }
    mc.advance(n * per);
  }

  /** Enables from the next one up to and including system cycle `target`. */
  enablesUntil(mc, target) {
    // enable j (>= 1 from now) is at base + floor((k + j) * d / 256) <= target
    return Math.max(0, Math.floor(((target - mc.base + 1) * 256 - 1) / mc.div256) - mc.k);
  }
}
