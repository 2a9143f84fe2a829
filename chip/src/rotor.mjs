// The joint's motor shaft: a stepper rotor that follows the driver's microstep position, with end
// stops it cannot pass, and the AS5600 magnet on it.
//
// Units: usteps, 1/256 full step of a 200-step motor (51 200 per revolution, the firmware's unit);
// the AS5600 sees 4096 counts per revolution, 12.5 usteps a count.
// Mechanics: the rotor sits at its equilibrium, the driver position minus a slip that is a whole
// number of electrical periods (4 full steps, 1024 usteps). An end stop holds it back: while the
// driver runs on past it the rotor stays at the stop until the lead exceeds half an electrical
// period; then the field pulls it back one period (it loses 4 full steps and falls up to 2 full
// steps off the stop, as a blocked stepper buzzes) and it follows forward again. Once the driver
// comes back the rotor follows, offset by the slip; a stop taken away lets it snap to the field at
// once. With the driver off (ENN high, TOFF 0) the steps are dropped and the rotor keeps its place.
// No inertia or load lag: the rotor is where the last microstep put it.
export const USTEPS_PER_REV = 51200;
const PERIOD = 1024;

export class Rotor {
  /**
   * @param driver  the TMC2209 fake (position, powered(), onStep)
   * @param opts    { offsetCounts: 1000, encoderSign: 1 } where the magnet's zero sits and which way
   *                the sensor counts (+1: counts grow with the driver position and shaft = 0)
   */
  constructor(driver, { offsetCounts = 1000, encoderSign = 1 } = {}) {
    this.driver = driver;
    this.offsetCounts = offsetCounts;
    this.encoderSign = encoderSign;
    this.position = 0; // usteps
    this.slip = 0;
    this.low = null; // end stops in usteps (null: none)
    this.high = null;
    this.blockedSteps = 0; // driver steps that did not move the rotor
    this.capture = null; // step times (ns) while capturing
    driver.onStep = (field, nanos) => this.follow(field, nanos);
  }

  follow(field, nanos) {
    const before = this.position;
    this.place(field);
    if (this.position === before) this.blockedSteps++;
    if (this.capture && this.capture.length < 2_000_000) this.capture.push(nanos);
  }

  /** The rotor at its equilibrium for driver position `field`, held back by the stops. */
  place(field) {
    let free = field - this.slip;
    let pos = free;
    if (this.high !== null && free > this.high) {
      while (free - this.high > PERIOD / 2) {
        this.slip += PERIOD;
        free -= PERIOD;
      }
      pos = Math.min(free, this.high);
    } else if (this.low !== null && free < this.low) {
      while (this.low - free > PERIOD / 2) {
        this.slip -= PERIOD;
        free += PERIOD;
      }
      pos = Math.max(free, this.low);
    }
    this.position = pos;
  }

  /** The encoder's view in counts (0..4095 after wrapping by the sensor). */
  counts() {
    return this.offsetCounts + (this.encoderSign * this.position * 4096) / USTEPS_PER_REV;
  }

  degrees() {
    return (this.position * 360) / USTEPS_PER_REV;
  }

  /** End stops in motor degrees from the present position (null: none). */
  setStops(lowDeg, highDeg) {
    const at = (deg) => (deg === null || deg === undefined ? null : this.position + (deg * USTEPS_PER_REV) / 360);
    this.low = at(lowDeg);
    this.high = at(highDeg);
    this.place(this.driver.position); // a removed stop lets the rotor snap to the field at once
  }

  state() {
    return {
      position: this.position, degrees: this.degrees(), slip: this.slip, low: this.low, high: this.high,
      blockedSteps: this.blockedSteps, driverPosition: this.driver.position, steps: this.driver.steps,
    };
  }
}
