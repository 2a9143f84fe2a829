// An emulated Raspberry Pi Pico: rp2040js's RP2040 with the RP2040 bootrom, a UF2 in flash (stock
// MicroPython or CircuitPython), an optional filesystem image (MicroPython's littlefs or the
// CIRCUITPY FAT), and our datasheet fixes (PL011 transmit FIFO and interrupt; a USB host that NAKs
// OUT transfers until it has data; a flash chip the bootrom can erase and program; the BOOTSEL
// button released). It runs only when stepped, in emulated time, so a run is deterministic for a
// given sequence of inputs; several boards step together in a `World`.
import { readFileSync } from 'node:fs';
import { resolve } from 'node:path';
import { ConsoleLogger, LogLevel, RP2040, USBCDC } from 'rp2040js';
import { installFlash } from './flash.mjs';
import { BOOTROM_NAME, CIRCUITPYTHON_UF2_NAME, rp2040Dir, UF2_NAME } from './paths.mjs';
import { uf2Blocks } from './uf2.mjs';
import { installPL011 } from './uart.mjs';
import { PioClock } from './pio-clock.mjs';
import { HostCDC } from './usb-cdc.mjs';

export const DEFAULT_UF2 = resolve(rp2040Dir(), UF2_NAME);
export const DEFAULT_BOOTROM = resolve(rp2040Dir(), BOOTROM_NAME);
export const FLASH_BASE = 0x10000000;
export const FS_OFFSET = 0xa0000; // MicroPython RPI_PICO: littlefs v2, 352 blocks of 4096 bytes
export const FS_SIZE = 352 * 4096;
export const QSPI_SS = 1; // the flash chip select, GPIO_HI_IN bit 1: the BOOTSEL button's sense line
const QSPI_SS_PAD_RESET = 0x5a;

// What each firmware needs from flash: its UF2 and where its filesystem lives. CircuitPython 10.2.1
// (raspberry_pi_pico) keeps CIRCUITPY, FAT, in the second MiB of the 2 MiB flash (it reads the flash
// ID as 0 here and assumes 2 MiB).
export const RUNTIMES = {
  micropython: { uf2: resolve(rp2040Dir(), UF2_NAME), fsOffset: FS_OFFSET, fsSize: FS_SIZE },
  circuitpython: { uf2: resolve(rp2040Dir(), CIRCUITPYTHON_UF2_NAME), fsOffset: 0x100000, fsSize: 0x100000 },
};

export class Board {
  /**
   * @param {object} options
   * @param {string} [options.name] a label for logs and the control channel
   * @param {string} [options.runtime] 'micropython' (default) or 'circuitpython': the default UF2
   *   and where the filesystem image goes (RUNTIMES)
   * @param {string|Uint8Array} [options.uf2] firmware image (path or bytes)
   * @param {string|Uint8Array} [options.bootrom] RP2040 mask ROM (path or bytes)
   * @param {string|Uint8Array} [options.fs] filesystem image: littlefs at flash offset 0xA0000
   *   (MicroPython), FAT at 0x100000 (CircuitPython)
   * @param {boolean} [options.stockUsb] keep rp2040js's own USB CDC host (for tests of the fix)
   * @param {boolean} [options.stockUart] keep rp2040js's own UARTs (for tests of the fix)
   * @param {boolean} [options.stockPio] keep rp2040js's free-running PIO (for tests of the fix)
   * @param {boolean} [options.stockQspi] keep rp2040js's QSPI pads reading 0 (BOOTSEL held)
   */
  constructor({ name = 'pico', runtime = 'micropython', uf2 = null, bootrom = DEFAULT_BOOTROM, fs = null,
    stockUsb = false, stockUart = false, stockPio = false, stockQspi = false, logLevel = LogLevel.Error } = {}) {
    this.name = name;
    this.runtime = RUNTIMES[runtime];
    if (!this.runtime) throw new Error(`unknown runtime ${runtime}: one of ${Object.keys(RUNTIMES)}`);
    uf2 ??= this.runtime.uf2;
    const mcu = new RP2040(); // with its own SimulationClock: each board keeps its own time
    this.rp2040 = mcu;
    this.clock = mcu.clock;
    mcu.logger = new ConsoleLogger(logLevel);
    if (!stockUart) installPL011(mcu);
    this.pio = stockPio ? null : new PioClock(mcu, mcu.clock); // PIO on clk_sys through CLKDIV
    const rom = bytesOf(bootrom);
    mcu.loadBootrom(new Uint32Array(rom.buffer, rom.byteOffset, rom.byteLength >> 2)); // also erases flash
    installFlash(this);
    if (uf2) {
      for (const { address, payload } of uf2Blocks(bytesOf(uf2))) {
        mcu.flash.set(payload, address - FLASH_BASE);
      }
    }
    if (fs) this.writeFlash(this.runtime.fsOffset, bytesOf(fs), this.runtime.fsSize);
    // The flash chip select has a pull-up: with BOOTSEL released it reads 1 while it floats.
    // rp2040js leaves IO_QSPI unimplemented and its pads with input disabled, so every QSPI line
    // reads 0, which is the button held; CircuitPython samples it at boot (floats CS, reads
    // GPIO_HI_IN bit 1) and then waits forever. The SS pad gets its reset value (PADS_QSPI
    // GPIO_QSPI_SS 0x5a: input enabled, pull-up) and the line its level.
    if (!stockQspi) {
      mcu.qspi[QSPI_SS].padValue = QSPI_SS_PAD_RESET;
      mcu.qspi[QSPI_SS].setInputValue(true);
    }
    this.cdc = stockUsb ? new StockCDCAdapter(mcu.usbCtrl) : new HostCDC(mcu.usbCtrl);
    this.usbListeners = new Set();
    this.cdc.onSerialData = (buffer) => {
      for (const listener of this.usbListeners) listener(buffer);
    };
    this.cdc.onDeviceConnected = () => { this.usbConnected = true; };
    this.usbConnected = false;
    // Start at the flash's boot stage 2, as the bootrom does after checking its CRC.
    mcu.core.PC = FLASH_BASE;
  }

  writeFlash(offset, bytes, limit = bytes.length) {
    if (bytes.length > limit) throw new Error(`${bytes.length} bytes do not fit in ${limit}`);
    this.rp2040.flash.set(bytes, offset);
  }

  /** The filesystem region of flash (littlefs or FAT), as the firmware has left it. */
  fsImage() {
    const { fsOffset, fsSize } = this.runtime;
    return this.rp2040.flash.slice(fsOffset, fsOffset + fsSize);
  }

  /** Emulated time in nanoseconds since power-on. */
  get nanos() {
    return this.clock.nanos;
  }

  /** CPU cycles since power-on, at the current clk_sys. */
  get cycles() {
    return Math.round((this.clock.nanos * this.rp2040.clkSys) / 1e9);
  }

  get cycleNanos() {
    return 1e9 / this.rp2040.clkSys;
  }

  /**
   * Runs `callback(board)` when `cycles` more CPU cycles have elapsed; the hook for peripherals
   * (bus models, device fakes) to do work on the CPU clock. Returns a handle with `cancel()`.
   */
  afterCycles(cycles, callback) {
    return this.afterNanos(cycles * this.cycleNanos, callback);
  }

  /** Runs `callback(board)` at absolute CPU cycle `cycle` (at once if it has passed). */
  atCycle(cycle, callback) {
    return this.afterCycles(Math.max(0, cycle - this.cycles), callback);
  }

  afterNanos(nanos, callback) {
    const alarm = this.clock.createAlarm(() => {
      alarm.scheduled = false;
      callback(this);
    });
    alarm.schedule(Math.max(0, nanos));
    return { cancel: () => alarm.cancel(), get pending() { return alarm.scheduled; } };
  }

  /** Bytes from the USB host (the pseudo-terminal side) to the board. */
  usbWrite(bytes) {
    this.cdc.sendSerialBytes(bytes);
  }

  /** Subscribes `listener(Uint8Array)` to bytes the board sends over USB; returns unsubscribe. */
  onUsb(listener) {
    this.usbListeners.add(listener);
    return () => this.usbListeners.delete(listener);
  }

  /**
   * Executes instructions (and sleeps through WFI) until emulated time `nanos`. Between alarms the
   * clock is advanced in place; alarms fire through the clock's own tick, as rp2040js's Simulator
   * does it, at the first instruction boundary at or after their time.
   */
  runUntil(nanos) {
    const { clock, rp2040: mcu } = this;
    const core = mcu.core;
    while (clock.nanosCounter < nanos) {
      if (core.waiting) {
        const next = clock.nextAlarm ? clock.nextAlarm.nanos : nanos;
        clock.tick(Math.max(0, Math.min(next, nanos) - clock.nanosCounter));
        continue;
      }
      const cycleNanos = 1e9 / mcu.clkSys;
      for (;;) {
        const next = clock.nextAlarm;
        const stop = next !== null && next.nanos < nanos ? next.nanos : nanos;
        if (clock.nanosCounter >= stop || core.waiting) break;
        clock.nanosCounter += core.executeInstruction() * cycleNanos;
      }
      clock.tick(0); // fire the alarms that are due
    }
  }
}

/** Steps several boards together in emulated time, `quantumNanos` at a time each. */
export class World {
  constructor({ quantumNanos = 10_000 } = {}) {
    this.boards = [];
    this.quantumNanos = quantumNanos;
    this.nanos = 0;
    this.stepListeners = new Set();
  }

  add(board) {
    if (board.nanos !== this.nanos) throw new Error('a board joins the world at its current time');
    this.boards.push(board);
    return board;
  }

  /** Subscribes `listener(world)` to the end of every quantum; returns unsubscribe. */
  onStep(listener) {
    this.stepListeners.add(listener);
    return () => this.stepListeners.delete(listener);
  }

  /** Runs every board to emulated time `nanos`, one quantum at a time. */
  runUntil(nanos) {
    while (this.nanos < nanos) {
      const target = Math.min(nanos, this.nanos + this.quantumNanos);
      for (const board of this.boards) board.runUntil(target);
      this.nanos = target;
      for (const listener of this.stepListeners) listener(this);
    }
  }

  runFor(nanos) {
    this.runUntil(this.nanos + nanos);
  }

  /** Runs until `predicate()` holds (checked every quantum); false if `limitNanos` passed first. */
  runUntilTrue(predicate, limitNanos) {
    const end = this.nanos + limitNanos;
    while (!predicate()) {
      if (this.nanos >= end) return false;
      this.runUntil(Math.min(end, this.nanos + this.quantumNanos));
    }
    return true;
  }
}

/** rp2040js's own CDC host behind the same interface as HostCDC. */
class StockCDCAdapter {
  constructor(usb) {
    this.inner = new USBCDC(usb);
    this.usb = usb;
    this.inner.onSerialData = (buffer) => this.onSerialData?.(buffer);
    this.inner.onDeviceConnected = () => this.onDeviceConnected?.();
  }

  sendSerialBytes(bytes) {
    for (const byte of bytes) this.inner.sendSerialByte(byte);
  }
}

function bytesOf(source) {
  return typeof source === 'string' ? new Uint8Array(readFileSync(source)) : source;
}
