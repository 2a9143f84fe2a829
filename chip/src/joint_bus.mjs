// The joint bus: an emulated I2C controller on a board's I2C0, as a harness plugin.
//
// attach(world, boards, { board = first, khz = 400, i2c = 0 }) installs RP2040I2C on that board,
// puts a bit-timed controller on its I2C0 and meters the I2C IRQ handler. Control commands
// (harness.mjs "i2c.<command>"):
//   i2c.transfer {addr, write: [bytes], read: n, gapNs?}   -> one transaction's result
//   i2c.schedule {items: [{addr, write, read, gapNs?}], repeat?: k, periodNs?}
//        -> {results: [...]}: the items back to back (each after its gapNs), k times; with
//           periodNs each repetition starts periodNs after the previous one started (host cycling)
//   i2c.cycle {items, periodNs, repeat}  starts such a schedule and returns at once (a host
//        cycling in the background); i2c.state then reports how many transactions ended/failed
//   i2c.config {khz}                                          -> the bus clock
// A result: {addr, write, read, ack, data, startNs, endNs, totalNs, heldNs, wireNs, bits, irqNs}
// (times in emulated ns; heldNs is SCL held low by the target; irqNs the target CPU's time in its
// I2C interrupt handler from the START until the handler is idle after the STOP).
import { installI2C } from './i2c_target.mjs';
import { I2CController } from './i2c_controller.mjs';
import { IrqMeter } from './irq_meter.mjs';

export class JointBus {
  constructor(board, { khz = 400, i2c = 0 } = {}) {
    this.board = board;
    installI2C(board.rp2040, [i2c]);
    this.target = board.rp2040.i2c[i2c];
    this.meter = new IrqMeter(board.rp2040, 23 + i2c);
    this.controller = new I2CController(board.clock, { khz }).attach(this.target).meterIrq(this.meter);
    this.cycling = null; // counts of a background host cycle (i2c.cycle)
  }

  set khz(value) {
    this.controller.khz = value;
  }

  get khz() {
    return this.controller.khz;
  }

  /** What the bus is doing, for diagnosis. */
  state() {
    const t = this.target;
    const c = this.controller;
    return {
      nanos: this.board.nanos, queued: c.queue.length, busy: !!c.current,
      holdingScl: t.holdingScl, readHold: !!t.readHold, rxHold: !!t.rxHold, txFlushed: t.txFlushed,
      rxLevel: t.rxFIFO.itemCount, txLevel: t.txFIFO.itemCount, raw: t.intRaw, mask: t.intEnable,
      enabled: t.enable & 1, con: t.control, irqEntries: this.meter.entries, irqIdle: this.meter.idle,
      irqStack: this.meter.t.stack.slice(), cycling: this.cycling,
    };
  }

  transfer(spec) {
    return this.controller.run(spec);
  }

  /**
   * Items back to back, `repeat` times; with periodNs, repetitions start periodNs apart. All are
   * queued at once, so they follow each other on the emulated clock, not on the host's.
   */
  schedule({ items, repeat = 1, periodNs = 0 }) {
    const t0 = this.board.nanos;
    const jobs = [];
    for (let k = 0; k < repeat; k++) {
      items.forEach((item, i) => {
        const atNs = periodNs && i === 0 ? t0 + k * periodNs : 0;
        jobs.push(new Promise((resolve) => this.controller.transfer({ ...item, atNs }, (r) => {
          if (this.cycling) {
            this.cycling.ended++;
            if (!r.ack) this.cycling.failed++;
          }
          resolve(r);
        })));
      });
    }
    return Promise.all(jobs);
  }
}

export function attach(world, boards, options = {}) {
  const board = options.board ? boards.get(options.board) : boards.values().next().value;
  if (!board) throw new Error(`no board ${options.board}`);
  const bus = new JointBus(board, options);
  return {
    name: options.name ?? 'i2c',
    bus,
    control: async (command, msg) => {
      switch (command) {
        case 'transfer':
          return bus.transfer(msg);
        case 'schedule':
          return { results: await bus.schedule(msg) };
        case 'cycle':
          bus.cycling = { ended: 0, failed: 0 };
          bus.schedule(msg).then(() => {});
          return { started: true };
        case 'state':
          return bus.state();
        case 'config':
          if (msg.khz) bus.khz = Number(msg.khz);
          return { khz: bus.khz };
        default:
          throw new Error(`unknown i2c command ${command}`);
      }
    },
  };
}
