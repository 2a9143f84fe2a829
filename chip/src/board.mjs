// An emulated Raspberry Pi Pico: rp2040js's RP2040 with the RP2040 bootrom, a UF2 in flash, an
// optional littlefs image, and our datasheet fixes (PL011 transmit FIFO and interrupt; a USB host
// that NAKs OUT transfers until it has data; a flash chip the bootrom can erase and program). It runs only when stepped, in emulated time, so a run
// is deterministic for a given sequence of inputs; several boards step together in a `World`.
import { readFileSync } from 'node:fs';
import { resolve } from 'node:path';
import { ConsoleLogger, LogLevel, RP2040, USBCDC } from 'rp2040js';
import { installFlash } from './flash.mjs';
import { BOOTROM_NAME, rp2040Dir, UF2_NAME } from './paths.mjs';
import { uf2Blocks } from './uf2.mjs';
import { installPL011 } from './uart.mjs';
import { HostCDC } from './usb-cdc.mjs';

export const DEFAULT_UF2 = resolve(rp2040Dir(), UF2_NAME);
export const DEFAULT_BOOTROM = resolve(rp2040Dir(), BOOTROM_NAME);
export const FLASH_BASE = 0x10000000;
export const FS_OFFSET = 0xa0000; // MicroPython RPI_PICO: littlefs v2, 352 blocks of 4096 bytes
export const FS_SIZE = 352 * 4096;

export class Board {
  /**
   * @param {object} options
   * @param {string} [options.name] a label for logs and the control channel
   * @param {string|Uint8Array} [options.uf2] firmware image (path or bytes)
   * @param {string|Uint8Array} [options.bootrom] RP2040 mask ROM (path or bytes)
   * @param {string|Uint8Array} [options.fs] littlefs image written at flash offset 0xA0000
   * @param {boolean} [options.stockUsb] keep rp2040js's own USB CDC host (for tests of the fix)
   * @param {boolean} [options.stockUart] keep rp2040js's own UARTs (for tests of the fix)
   */
  constructor({ name = 'pico', uf2 = DEFAULT_UF2, bootrom = DEFAULT_BOOTROM, fs = null,
    stockUsb = false, stockUart = false, logLevel = LogLevel.Error } = {}) {
    this.name = name;
    const mcu = new RP2040(); // with its own SimulationClock: each board keeps its own time
    this.rp2040 = mcu;
    this.clock = mcu.clock;
    mcu.logger = new ConsoleLogger(logLevel);
    if (!stockUart) installPL011(mcu);
    const rom = bytesOf(bootrom);
    mcu.loadBootrom(new Uint32Array(rom.buffer, rom.byteOffset, rom.byteLength >> 2)); // also erases flash
    installFlash(this);
    if (uf2) {
      for (const { address, payload } of uf2Blocks(bytesOf(uf2))) {
        mcu.flash.set(payload, address - FLASH_BASE);
      }
    }
    if (fs) this.writeFlash(FS_OFFSET, bytesOf(fs), FS_SIZE);
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

  /** The filesystem region of flash (littlefs), as MicroPython has left it. */
  fsImage() {
    return this.rp2040.flash.slice(FS_OFFSET, FS_OFFSET + FS_SIZE);
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
