// Where the emulated Pico's binaries are: $BIOSCARA_RP2040, else ../shared/rp2040 next to the
// repository, else next to the main checkout when this repository is a git worktree of it.
import { existsSync, readFileSync, statSync } from 'node:fs';
import { dirname, resolve } from 'node:path';
import { fileURLToPath } from 'node:url';

export const REPO = resolve(dirname(fileURLToPath(import.meta.url)), '../..');
export const UF2_NAME = 'micropython-v1.28.0-RPI_PICO.uf2';
export const CIRCUITPYTHON_UF2_NAME = 'circuitpython-10.2.1-raspberry_pi_pico.uf2';
export const BOOTROM_NAME = 'rp2040-bootrom-B1.bin';

function mainCheckout(repo) {
  const dotGit = resolve(repo, '.git');
  if (!existsSync(dotGit) || statSync(dotGit).isDirectory()) return null;
  const gitdir = readFileSync(dotGit, 'utf8').match(/^gitdir:\s*(.+)$/m)?.[1].trim();
  if (!gitdir) return null;
  const common = resolve(gitdir, readFileSync(resolve(gitdir, 'commondir'), 'utf8').trim());
  return dirname(common);
}

export function rp2040Dir() {
  if (process.env.BIOSCARA_RP2040) return resolve(process.env.BIOSCARA_RP2040);
  const candidates = [resolve(REPO, '../shared/rp2040')];
  const main = mainCheckout(REPO);
  if (main) candidates.push(resolve(main, '../shared/rp2040'));
  return candidates.find((dir) => existsSync(resolve(dir, UF2_NAME))) ?? candidates[0];
}
