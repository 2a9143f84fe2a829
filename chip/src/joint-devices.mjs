// The joint's devices on an emulated Pico, wired as firmware/joint/pico/motor.py DEFAULT_PINS says:
// a TMC2209 on UART1 (TX GP8, RX GP9, node 0) driving STEP GP10 / DIR GP11 / ENN GP12, and an
// AS5600 on I2C1 (SDA GP6, SCL GP7) whose magnet sits on the rotor the driver turns.
import { AS5600, AS5600_ADDRESS } from './as5600.mjs';
import { TimedI2CController } from './i2c-controller.mjs';
import { Rotor } from './rotor.mjs';
import { TMC2209 } from './tmc2209.mjs';

export class JointDevices {
  constructor(board, { node = 0, offsetCounts = 1000, encoderSign = 1, seed = 1 } = {}) {
    this.board = board;
    this.driver = new TMC2209(board, { uart: 1, node });
    this.rotor = new Rotor(this.driver, { offsetCounts, encoderSign });
    this.encoderBus = new TimedI2CController(board, 1, { pullups: [6, 7] });
    this.encoder = this.encoderBus.attach(AS5600_ADDRESS, new AS5600(() => this.rotor.counts(), { seed }));
  }

  /** Everything a test may want to look at, JSON-friendly. */
  state() {
    return {
      nanos: this.board.nanos, driver: this.driver.state(), rotor: this.rotor.state(),
      encoder: this.encoder.state(),
      encoderBus: { sclHz: this.encoderBus.sclHz, transactions: this.encoderBus.transactions,
        busyNanos: this.encoderBus.busyNanos },
    };
  }

  /**
   * The control commands (for chip/board.py's control channel): returns a JSON-friendly result.
   *   state                                     everything above
   *   stops {low, high}                         end stops in motor degrees from here (null: none)
   *   driver_faults {badCrc, silent, ignoreWrites, absent, echo}
   *   encoder_faults {nack, absent, noise, magnet}
   *   capture_steps {on}                        record STEP times; off returns them (ns)
   */
  control(command, args = {}) {
    switch (command) {
      case 'state':
        return this.state();
      case 'stops':
        this.rotor.setStops(args.low ?? null, args.high ?? null);
        return this.rotor.state();
      case 'driver_faults':
        for (const key of ['badCrc', 'silent', 'ignoreWrites']) {
          if (key in args) this.driver.faults[key] = args[key];
        }
        if ('absent' in args) this.driver.absent = !!args.absent;
        if ('echo' in args) this.driver.echo = !!args.echo;
        return this.driver.state();
      case 'encoder_faults':
        for (const key of ['nack', 'noise']) {
          if (key in args) this.encoder[key] = args[key];
        }
        if ('absent' in args) this.encoder.absent = !!args.absent;
        if ('magnet' in args) this.encoder.magnet = args.magnet;
        return this.encoder.state();
      case 'capture_steps': {
        if (args.on) {
          this.rotor.capture = [];
          return { capturing: true };
        }
        const times = this.rotor.capture ?? [];
        this.rotor.capture = null;
        return { times };
      }
      default:
        throw new Error(`unknown joint-device command ${command}`);
    }
  }
}

/** Harness plugin (chip/src/harness.mjs): options { board, node, offsetCounts, encoderSign, seed }. */
export function attach(world, boards, options = {}) {
  const board = options.board ? boards.get(options.board) : boards.values().next().value;
  if (!board) throw new Error(`joint devices: no board ${options.board}`);
  const devices = new JointDevices(board, options);
  return { name: options.name ?? 'joint', control: (command, msg) => devices.control(command, msg) };
}
