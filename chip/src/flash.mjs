// The QSPI flash chip behind the bootrom's flash functions.
//
// rp2040js 1.4.1 reads flash but cannot write it: its SSI ignores the flash commands, so
// MicroPython cannot format or write its littlefs (mkfs fails with ENOSPC, file writes with
// ENODEV). The bootrom's own `flash_range_erase` ('RE') and `flash_range_program` ('RP'), which the
// pico-sdk's flash_range_* call, are trapped here (their first instruction becomes a BKPT) and do
// what the W25Q16JV on a Pico does: erase sets 4 KiB sectors (or aligned 64 KiB blocks) to 0xFF,
// program ANDs bytes into erased flash. The CPU is stalled for the chip's typical times (W25Q16JV
// datasheet: page program 0.4 ms, sector erase 45 ms, 64 KiB block erase 150 ms).
const CODE = (a, b) => a.charCodeAt(0) | (b.charCodeAt(0) << 8);
const SECTOR = 4096;
const BLOCK = 65536;
const PAGE = 256;
export const FLASH_NANOS = { page: 0.4e6, sector: 45e6, block: 150e6 };

/** The bootrom's function table: code ('RE' etc.) -> thumb address. */
export function romFunctions(rp2040) {
  const rom = new DataView(rp2040.bootrom.buffer);
  const functions = new Map();
  for (let at = rom.getUint16(0x14, true); ; at += 4) {
    const code = rom.getUint16(at, true);
    if (!code) break;
    functions.set(code, rom.getUint16(at + 2, true));
  }
  return functions;
}

export function installFlash(board) {
  const mcu = board.rp2040;
  const functions = romFunctions(mcu);
  const traps = new Map();
  const trap = (code, number, action) => {
    const address = functions.get(code) & ~1;
    const word = mcu.bootrom[address >> 2];
    const shift = (address & 2) * 8;
    mcu.bootrom[address >> 2] = (word & ~(0xffff << shift)) | ((0xbe00 | number) << shift);
    traps.set(number, action);
  };
  const stall = (nanos) => board.clock.tick(nanos);
  trap(CODE('R', 'E'), 0x52, (offset, count, blockSize) => {
    offset &= ~(SECTOR - 1);
    const end = offset + count;
    while (offset < end) {
      const block = blockSize === BLOCK && !(offset % BLOCK) && end - offset >= BLOCK;
      const size = block ? BLOCK : SECTOR;
      mcu.flash.fill(0xff, offset, offset + size);
      stall(block ? FLASH_NANOS.block : FLASH_NANOS.sector);
      offset += size;
    }
  });
  trap(CODE('R', 'P'), 0x50, (offset, data, count) => {
    for (let i = 0; i < count; i++) mcu.flash[offset + i] &= mcu.readUint8(data + i);
    stall(Math.ceil(count / PAGE) * FLASH_NANOS.page);
  });
  const previous = mcu.onBreak;
  mcu.onBreak = (number) => {
    const action = traps.get(number);
    if (!action) return previous(number);
    const core = mcu.core;
    const r = core.registers;
    action(r[0] >>> 0, r[1] >>> 0, r[2] >>> 0, r[3] >>> 0);
    core.PC = core.LR & ~1; // return to the caller, as the ROM function would
  };
}
