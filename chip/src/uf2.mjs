// UF2 image parsing (https://github.com/microsoft/uf2): 512-byte blocks, each carrying up to 476
// payload bytes and the flash address they belong at.
const MAGIC_START0 = 0x0a324655;
const MAGIC_START1 = 0x9e5d5157;
const MAGIC_END = 0x0ab16f30;
const FLAG_NOT_MAIN_FLASH = 0x1;
const BLOCK = 512;

/** Yields {address, payload} for every main-flash block of a UF2 file's bytes. */
export function* uf2Blocks(bytes) {
  const view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  for (let at = 0; at + BLOCK <= bytes.length; at += BLOCK) {
    if (view.getUint32(at, true) !== MAGIC_START0 || view.getUint32(at + 4, true) !== MAGIC_START1
        || view.getUint32(at + BLOCK - 4, true) !== MAGIC_END) {
      throw new Error(`not a UF2 block at byte ${at}`);
    }
    if (view.getUint32(at + 8, true) & FLAG_NOT_MAIN_FLASH) continue;
    const address = view.getUint32(at + 12, true);
    const size = view.getUint32(at + 16, true);
    yield { address, payload: bytes.subarray(at + 32, at + 32 + size) };
  }
}
