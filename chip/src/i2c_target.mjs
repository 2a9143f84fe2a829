// The RP2040's I2C block (Synopsys DW_apb_i2c, RP2040 datasheet section 4.3) with the target
// (slave) mode that rp2040js 1.4.1 lacks, and the register behaviour it gets wrong.
//
// What this adds to rp2040js's RPI2C (its controller mode is kept, callbacks included):
// - IC_INTR_MASK is a register (reset value 0x8ff); IC_INTR_STAT = IC_RAW_INTR_STAT & mask, and
//   the NVIC line follows it. rp2040js ignores mask writes, so no I2C interrupt ever fired.
// - RX_FULL and TX_EMPTY are levels (FIFO level against IC_RX_TL / IC_TX_TL), not latches that a
//   single IC_DATA_CMD read clears while bytes remain.
// - Target mode (IC_CON.MASTER_MODE = 0, IC_SLAVE_DISABLE = 0, IC_ENABLE = 1): a bus controller
//   calls the bus-side methods below. IC_SAR (7-bit) is matched; received bytes enter the 16-deep
//   RX FIFO (FIRST_DATA_BYTE is bit 11, as the datasheet says); with RX_FIFO_FULL_HLD_CTRL the
//   target holds SCL while the FIFO is full (without it RX_OVER is raised and the byte is lost);
//   a read with an empty TX FIFO raises RD_REQ and holds SCL until a byte is written to
//   IC_DATA_CMD; data left in the TX FIFO when a read is addressed is flushed with TX_ABRT
//   (ABRT_SLVFLUSH_TXFIFO, TX_FLUSH_CNT) and the FIFO stays flushed until IC_CLR_TX_ABRT is read;
//   the controller's NAK raises RX_DONE; START_DET on every START, RESTART_DET on a repeated
//   START while addressed, STOP_DET (only if addressed when IC_CON.STOP_DET_IFADDRESSED);
//   IC_STATUS.SLV_ACTIVITY; IC_CLR_RESTART_DET; IC_CLR_INTR clears RESTART_DET too.
// - In target mode a write to IC_DATA_CMD is TX data only: rp2040js would start a controller
//   transfer with it.
//
// Not modelled: 10-bit target addresses, general call, SDA hold/setup times, DMA handshakes.
import { RPI2C } from 'rp2040js';

const IC_CON = 0x00;
const IC_DATA_CMD = 0x10;
const IC_INTR_STAT = 0x2c;
const IC_INTR_MASK = 0x30;
const IC_RAW_INTR_STAT = 0x34;
const IC_CLR_INTR = 0x40;
const IC_CLR_RD_REQ = 0x50;
const IC_CLR_TX_ABRT = 0x54;
const IC_CLR_RX_DONE = 0x58;
const IC_CLR_ACTIVITY = 0x5c;
const IC_CLR_STOP_DET = 0x60;
const IC_CLR_START_DET = 0x64;
const IC_ENABLE = 0x6c;
const IC_STATUS = 0x70;
const IC_TX_ABRT_SOURCE = 0x80;
const IC_ENABLE_STATUS = 0x9c;
const IC_CLR_RESTART_DET = 0xa8;

const MASTER_MODE = 1 << 0;
const IC_SLAVE_DISABLE = 1 << 6;
const STOP_DET_IFADDRESSED = 1 << 7;
const RX_FIFO_FULL_HLD_CTRL = 1 << 9;

export const R_RX_UNDER = 1 << 0;
export const R_RX_OVER = 1 << 1;
export const R_RX_FULL = 1 << 2;
export const R_TX_OVER = 1 << 3;
export const R_TX_EMPTY = 1 << 4;
export const R_RD_REQ = 1 << 5;
export const R_TX_ABRT = 1 << 6;
export const R_RX_DONE = 1 << 7;
export const R_ACTIVITY = 1 << 8;
export const R_STOP_DET = 1 << 9;
export const R_START_DET = 1 << 10;
export const R_GEN_CALL = 1 << 11;
export const R_RESTART_DET = 1 << 12;
const R_ALL = 0x1fff;
const R_SOFT_CLEARABLE = R_ALL & ~(R_RX_FULL | R_TX_EMPTY);

const ST_ACTIVITY = 1 << 0;
const ST_TFNF = 1 << 1;
const ST_TFE = 1 << 2;
const ST_RFNE = 1 << 3;
const ST_RFF = 1 << 4;
const ST_SLV_ACTIVITY = 1 << 6;

export const ABRT_SLVFLUSH_TXFIFO = 1 << 13;
const TX_FLUSH_CNT_SHIFT = 23;
const FIRST_DATA_BYTE = 1 << 11;
const INTR_MASK_RESET = 0x8ff;

export class RP2040I2C extends RPI2C {
  constructor(mcu, name, irq) {
    super(mcu, name, irq);
    this.intEnable = INTR_MASK_RESET;
    this.addressed = false; // this target ACKed its address since the last (repeated) START
    this.seenInTransfer = false; // addressed at any point since the last START (for STOP_DET)
    this.firstRxByte = false;
    this.readStarting = false;
    this.txFlushed = false; // TX FIFO held flushed until IC_CLR_TX_ABRT
    this.readHold = null; // controller waiting (SCL low) for TX data
    this.rxHold = null; // controller waiting (SCL low) for RX FIFO space: { byte, resume }
  }

  get targetMode() {
    return !(this.control & MASTER_MODE) && !(this.control & IC_SLAVE_DISABLE);
  }

  get targetActive() {
    return this.targetMode && !!(this.enable & 1);
  }

  /** The raw interrupt bits with the FIFO-level ones recomputed. */
  levels() {
    let raw = this.intRaw & ~(R_RX_FULL | R_TX_EMPTY);
    if (this.rxFIFO.itemCount > this.rxThreshold) raw |= R_RX_FULL;
    if ((this.enable & 1) && this.txFIFO.itemCount <= this.txThreshold) raw |= R_TX_EMPTY;
    if (raw !== this.intRaw) {
      this.intRaw = raw;
    }
    this.checkInterrupts();
  }

  setInterrupts(mask) {
    this.intRaw |= mask;
    this.checkInterrupts();
  }

  // ---- bus side: a controller on the same bus calls these at the bus events ----

  /** A START (repeated = false) or repeated START condition on the bus. */
  busStart(repeated) {
    if (!this.targetActive) return;
    let bits = R_START_DET | R_ACTIVITY;
    if (repeated && this.addressed) bits |= R_RESTART_DET;
    if (!repeated) this.seenInTransfer = false;
    this.addressed = false;
    this.setInterrupts(bits);
  }

  /** The address byte has been clocked in; returns true to ACK it. */
  busAddress(addr, read) {
    if (!this.targetActive || addr !== (this.slaveAddress & 0x7f) || addr === 0) {
      this.addressed = false;
      return false;
    }
    this.addressed = true;
    this.seenInTransfer = true;
    this.firstRxByte = !read;
    this.readStarting = read;
    return true;
  }

  /**
   * A data byte from the controller has been clocked in (before its ACK bit). Returns true to
   * ACK now, or null when SCL is held (RX FIFO full with RX_FIFO_FULL_HLD_CTRL): `resume(true)` is
   * called once the FIFO has room.
   */
  busWriteByte(byte, resume) {
    if (!this.addressed) return false;
    if (this.rxFIFO.full) {
      if (this.control & RX_FIFO_FULL_HLD_CTRL) {
        this.rxHold = { byte, resume };
        return null;
      }
      this.setInterrupts(R_RX_OVER);
      return true;
    }
    this.pushTargetRx(byte);
    return true;
  }

  pushTargetRx(byte) {
    this.rxFIFO.push((byte & 0xff) | (this.firstRxByte ? FIRST_DATA_BYTE : 0));
    this.firstRxByte = false;
    this.levels();
  }

  /**
   * The controller wants the next byte. Returns it, or null while SCL is held (RD_REQ raised,
   * TX FIFO empty): `resume(byte)` is called when software has written it to IC_DATA_CMD.
   */
  busReadByte(resume) {
    if (!this.addressed) return 0xff;
    if (this.readStarting) {
      this.readStarting = false;
      if (!this.txFIFO.empty) {
        // Stale data from an earlier read: flushed, and the FIFO stays flushed until cleared.
        this.abortSource = ABRT_SLVFLUSH_TXFIFO | (this.txFIFO.itemCount << TX_FLUSH_CNT_SHIFT);
        this.txFIFO.reset();
        this.txFlushed = true;
        this.setInterrupts(R_TX_ABRT);
      }
    }
    if (!this.txFIFO.empty && !this.txFlushed) {
      const value = this.txFIFO.pull() & 0xff;
      this.levels();
      return value;
    }
    this.readHold = resume;
    this.setInterrupts(R_RD_REQ);
    return null;
  }

  /** The controller's ACK (true) or NAK (false) of a byte this target sent. */
  busReadAck(ack) {
    if (!ack && this.addressed) this.setInterrupts(R_RX_DONE);
  }

  /** A STOP condition. */
  busStop() {
    if (!this.targetActive) return;
    if (this.seenInTransfer || !(this.control & STOP_DET_IFADDRESSED)) {
      this.setInterrupts(R_STOP_DET);
    }
    this.addressed = false;
    this.seenInTransfer = false;
    this.readStarting = false;
  }

  /** True while this target holds SCL low. */
  get holdingScl() {
    return this.readHold !== null || this.rxHold !== null;
  }

  releaseHolds() {
    const readHold = this.readHold;
    const rxHold = this.rxHold;
    this.readHold = null;
    this.rxHold = null;
    if (readHold) readHold(0xff);
    if (rxHold) rxHold.resume(true);
  }

  // ---- CPU side ----

  readUint32(offset) {
    offset &= 0xfff;
    switch (offset) {
      case IC_DATA_CMD: {
        if (this.rxFIFO.empty) {
          this.setInterrupts(R_RX_UNDER);
          return 0;
        }
        const value = this.rxFIFO.pull();
        if (this.rxHold && this.targetMode) {
          const { byte, resume } = this.rxHold;
          this.rxHold = null;
          this.pushTargetRx(byte);
          resume(true);
        }
        this.levels();
        return value;
      }
      case IC_INTR_STAT:
        return this.intRaw & this.intEnable;
      case IC_INTR_MASK:
        return this.intEnable;
      case IC_RAW_INTR_STAT:
        return this.intRaw;
      case IC_CLR_INTR: {
        const any = this.intRaw & R_SOFT_CLEARABLE ? 1 : 0;
        this.abortSource = 0;
        this.txFlushed = false;
        this.intRaw &= ~(R_SOFT_CLEARABLE & ~(this.busActive ? R_ACTIVITY : 0));
        this.levels();
        return any;
      }
      case IC_CLR_TX_ABRT: {
        const any = this.intRaw & R_TX_ABRT ? 1 : 0;
        this.abortSource = 0;
        this.txFlushed = false;
        this.intRaw &= ~R_TX_ABRT;
        this.levels();
        return any;
      }
      case IC_CLR_ACTIVITY: {
        const any = this.intRaw & R_ACTIVITY ? 1 : 0;
        if (!this.busActive) this.intRaw &= ~R_ACTIVITY;
        this.levels();
        return any;
      }
      case IC_CLR_RD_REQ:
      case IC_CLR_RX_DONE:
      case IC_CLR_STOP_DET:
      case IC_CLR_START_DET:
      case IC_CLR_RESTART_DET: {
        const bit = {
          [IC_CLR_RD_REQ]: R_RD_REQ,
          [IC_CLR_RX_DONE]: R_RX_DONE,
          [IC_CLR_STOP_DET]: R_STOP_DET,
          [IC_CLR_START_DET]: R_START_DET,
          [IC_CLR_RESTART_DET]: R_RESTART_DET,
        }[offset];
        const any = this.intRaw & bit ? 1 : 0;
        this.intRaw &= ~bit;
        this.levels();
        return any;
      }
      case IC_STATUS: {
        let status = super.readUint32(IC_STATUS);
        if (this.targetMode && this.seenInTransfer) status |= ST_SLV_ACTIVITY | ST_ACTIVITY;
        return status;
      }
      case IC_TX_ABRT_SOURCE:
        return this.abortSource;
      case IC_ENABLE_STATUS:
        return this.enable & 1;
      default:
        return super.readUint32(offset);
    }
  }

  get busActive() {
    return this.seenInTransfer || this.state !== 0;
  }

  writeUint32(offset, value) {
    offset &= 0xfff;
    switch (offset) {
      case IC_INTR_MASK:
        this.intEnable = value & R_ALL;
        this.checkInterrupts();
        return;
      case IC_DATA_CMD:
        if (this.targetMode) {
          if (this.txFlushed) return; // held flushed until IC_CLR_TX_ABRT is read
          if (this.txFIFO.full) {
            this.setInterrupts(R_TX_OVER);
            return;
          }
          this.txFIFO.push(value & 0xff);
          if (this.readHold) {
            const resume = this.readHold;
            this.readHold = null;
            const byte = this.txFIFO.pull() & 0xff;
            this.levels();
            resume(byte);
            return;
          }
          this.levels();
          return;
        }
        super.writeUint32(offset, value);
        this.levels();
        return;
      case IC_ENABLE:
        super.writeUint32(offset, value);
        if (!(value & 1)) {
          this.txFlushed = false;
          this.releaseHolds(); // a disabled target lets go of SCL
        }
        this.levels();
        return;
      case IC_CON:
        super.writeUint32(offset, value);
        this.levels();
        return;
      default:
        super.writeUint32(offset, value);
        this.levels();
    }
  }
}

/**
 * Replace rp2040js's I2C blocks `indices` with RP2040I2C (once, before the CPU runs and before
 * anything wraps them); returns mcu.i2c.
 */
export function installI2C(mcu, indices = [0, 1]) {
  const bases = [0x40044, 0x40048];
  for (const index of indices) {
    const old = mcu.i2c[index];
    if (old instanceof RP2040I2C) continue;
    const block = new RP2040I2C(mcu, old.name, old.irq);
    mcu.i2c[index] = block;
    mcu.peripherals[bases[index]] = block;
  }
  return mcu.i2c;
}
