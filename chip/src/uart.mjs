// The PL011 UART as the RP2040 datasheet (section 4.2) describes it, on top of rp2040js's RPUART.
//
// rp2040js 1.4.1 has no transmit FIFO: every byte leaves at once and the transmit interrupt is set
// again by every register access, so once MicroPython's machine.UART enables TXIM its interrupt
// handler is re-entered forever. Here, as on the silicon:
// - a 32-deep TX FIFO (1 deep when UARTLCR_H.FEN is clear) drains into a shift register at the
//   programmed baud rate and frame format; `onByte` fires when a character's last stop bit ends;
// - TXRIS is set when the FIFO level falls through the UARTIFLS.TXIFLSEL trigger level (a
//   transition, not a level: an empty FIFO after enabling raises nothing), and is cleared by
//   writing TXIC to UARTICR or by writes that fill the FIFO above the trigger level;
// - UARTFR reports TXFF, TXFE and BUSY from that FIFO and shift register; UARTIFLS reads back.
// The receive path is rp2040js's (an interrupt per received byte).
const UARTDR = 0x0;
const UARTFR = 0x18;
const UARTIFLS = 0x34;
const UARTLCR_H = 0x2c;
const UARTCR = 0x30;

const FR_TXFE = 1 << 7;
const FR_RXFF = 1 << 6;
const FR_TXFF = 1 << 5;
const FR_RXFE = 1 << 4;
const FR_BUSY = 1 << 3;
const LCR_PEN = 1 << 1;
const LCR_STP2 = 1 << 3;
const LCR_FEN = 1 << 4;
const CR_UARTEN = 1 << 0;
const CR_TXE = 1 << 8;
const TXRIS = 1 << 5;

const FIFO_DEPTH = 32;
const IFLS_RESET = 0x12; // both trigger levels at 1/2 full
// TXIFLSEL: FIFO <= 1/8, 1/4, 1/2, 3/4, 7/8 full (datasheet table "UARTIFLS")
const TX_TRIGGER_EIGHTHS = [1, 2, 4, 6, 7];

// rp2040js does not export RPUART, so the class is made from the one an RP2040 instance uses.
const pl011 = (RPUART) => class PL011 extends RPUART {
  constructor(rp2040, name, irq, dreq) {
    super(rp2040, name, irq, dreq);
    this.ifls = IFLS_RESET;
    this.txFIFO = [];
    this.shifting = false;
    this.shiftAlarm = rp2040.clock.createAlarm(() => this.characterSent());
    this.shiftValue = 0;
  }

  get txDepth() {
    return this.lineCtrlRegister & LCR_FEN ? FIFO_DEPTH : 1;
  }

  /** The TX FIFO level at or below which TXRIS is raised when the level falls to it. */
  get txTrigger() {
    if (!(this.lineCtrlRegister & LCR_FEN)) return 0;
    const eighths = TX_TRIGGER_EIGHTHS[this.ifls & 0x7] ?? 4;
    return (FIFO_DEPTH * eighths) / 8;
  }

  /** Nanoseconds on the wire for one character: start, data, parity and stop bits. */
  get characterNanos() {
    const lcr = this.lineCtrlRegister;
    const bits = 1 + this.wordLength + (lcr & LCR_PEN ? 1 : 0) + (lcr & LCR_STP2 ? 2 : 1);
    return (bits * 16 * this.baudDivider * 1e9) / this.rp2040.clkPeri;
  }

  get flags() {
    const n = this.txFIFO.length;
    return (this.rxFIFO.full ? FR_RXFF : 0) | (this.rxFIFO.empty ? FR_RXFE : 0)
      | (n >= this.txDepth ? FR_TXFF : 0) | (n === 0 ? FR_TXFE : 0)
      | (this.shifting || n > 0 ? FR_BUSY : 0);
  }

  checkInterrupts() {
    this.rp2040.setInterrupt(this.irq, !!(this.interruptStatus & this.interruptMask));
  }

  readUint32(offset) {
    if (offset === UARTIFLS) return this.ifls;
    return super.readUint32(offset);
  }

  writeUint32(offset, value) {
    switch (offset) {
      case UARTDR:
        this.pushTx(value & 0xff);
        return;
      case UARTIFLS:
        this.ifls = value & 0x3f;
        return;
      case UARTLCR_H:
      case UARTCR:
        super.writeUint32(offset, value);
        this.startShifting();
        return;
      default:
        super.writeUint32(offset, value);
    }
  }

  pushTx(value) {
    if (this.txFIFO.length >= this.txDepth) return; // overrun: the silicon drops the write too
    this.txFIFO.push(value);
    if (this.txFIFO.length > this.txTrigger && this.interruptStatus & TXRIS) {
      this.interruptStatus &= ~TXRIS;
      this.checkInterrupts();
    }
    this.startShifting();
  }

  startShifting() {
    const ready = (this.ctrlRegister & (CR_UARTEN | CR_TXE)) === (CR_UARTEN | CR_TXE);
    if (this.shifting || !ready || !this.txFIFO.length || !this.baudDivider) return;
    const before = this.txFIFO.length;
    this.shiftValue = this.txFIFO.shift();
    this.shifting = true;
    const trigger = this.txTrigger;
    if (before > trigger && this.txFIFO.length <= trigger) {
      this.interruptStatus |= TXRIS;
      this.checkInterrupts();
    }
    this.shiftAlarm.schedule(this.characterNanos);
  }

  characterSent() {
    this.shifting = false;
    this.onByte?.(this.shiftValue);
    this.startShifting();
  }
};

let PL011 = null;

/** The PL011 class (a subclass of rp2040js's RPUART), given any RP2040 instance. */
export function pl011Class(rp2040) {
  PL011 ??= pl011(Object.getPrototypeOf(rp2040.uart[0]).constructor);
  return PL011;
}

/** Replaces both of `rp2040`'s UARTs with PL011s (before the firmware runs). */
export function installPL011(rp2040) {
  const bases = [0x40034, 0x40038];
  const PL011 = pl011Class(rp2040);
  rp2040.uart = rp2040.uart.map((old, i) => {
    const uart = new PL011(rp2040, old.name, old.irq, old.dreq);
    rp2040.peripherals[bases[i]] = uart;
    return uart;
  });
}
