// The emulated Picos as a process: `node harness.mjs '<config JSON>'`.
//
// config: {
//   boards: [{ name, uf2?, bootrom?, fs?, usbFd? }],   // usbFd: a socket carrying that board's USB CDC
//   quantumNanos?: 10000,                              // World step (see board.mjs)
//   plugins?: [{ module, options? }],                  // device models: module exports attach(world, boards, options)
//   paused?: false,                                    // start without running
//   realtime?: true,                                   // free-running: never ahead of wall time
// }
// Control channel: JSON lines on stdin (requests {id, cmd, ...}) and stdout (replies {id, ok, ...}
// or {id, ok: false, error}; events {event, ...}). Commands: time, pause, resume, run {nanos},
// fs {board} (its littlefs region, base64), stop, and "<plugin>.<command>" for a plugin whose attach() returned {name, control(cmd, msg)}.
// The boards run free unless paused: as fast as the host allows, but (with realtime) never ahead of
// wall time, so an idle board sleeping in WFI does not race ahead of the program talking to it.
// "run" steps a paused world deterministically.
import net from 'node:net';
import { createInterface } from 'node:readline';
import { pathToFileURL } from 'node:url';
import { resolve } from 'node:path';
import { Board, World } from './board.mjs';

// Free-running: yield to I/O at least this often, and at once when a board has sent USB data, so
// a program talking to a board over its pty waits for the emulator as little as possible.
const WALL_SLICE_MS = 2;

function send(message) {
  process.stdout.write(`${JSON.stringify(message)}\n`);
}

function timeReport(world, boards) {
  const report = { nanos: world.nanos, seconds: world.nanos / 1e9, boards: {} };
  for (const [name, board] of boards) report.boards[name] = { nanos: board.nanos, cycles: board.cycles };
  return report;
}

async function main() {
  const config = JSON.parse(process.argv[2] ?? '{}');
  const world = new World({ quantumNanos: config.quantumNanos ?? 10_000 });
  const boards = new Map();
  let usbSent = false;
  for (const spec of config.boards ?? [{ name: 'pico' }]) {
    const board = world.add(new Board(spec));
    boards.set(board.name, board);
    if (spec.usbFd != null) connectUsb(board, spec.usbFd);
    board.onUsb(() => { usbSent = true; });
  }
  const controls = new Map();
  for (const plugin of config.plugins ?? []) {
    const module = await import(pathToFileURL(resolve(plugin.module)).href);
    const control = await module.attach(world, boards, plugin.options ?? {});
    if (control?.name) controls.set(control.name, control);
  }

  const realtime = config.realtime ?? true;
  let paused = !!config.paused;
  let running = false;
  let stopping = false;
  let wallStart = performance.now();
  let emulatedStart = world.nanos;
  const loop = () => {
    running = false;
    if (paused || stopping) return;
    const until = performance.now() + WALL_SLICE_MS;
    let ahead = false;
    usbSent = false;
    while (performance.now() < until && !usbSent) {
      const limit = realtime ? emulatedStart + (performance.now() - wallStart) * 1e6 : Infinity;
      if (world.nanos >= limit) {
        ahead = true;
        break;
      }
      world.runUntil(Math.min(limit, world.nanos + 20 * world.quantumNanos));
    }
    running = true;
    if (ahead) setTimeout(loop, 1);
    else setImmediate(loop);
  };
  const kick = () => {
    if (running || paused) return;
    wallStart = performance.now();
    emulatedStart = world.nanos;
    running = true;
    setImmediate(loop);
  };

  const handlers = {
    time: () => timeReport(world, boards),
    pause: () => { paused = true; return timeReport(world, boards); },
    resume: () => { paused = false; kick(); return timeReport(world, boards); },
    run: (msg) => {
      if (!paused) throw new Error('run steps a paused world: pause first');
      world.runFor(Number(msg.nanos));
      return timeReport(world, boards);
    },
    fs: (msg) => ({ image: Buffer.from(boardNamed(boards, msg.board).fsImage()).toString('base64') }),
    stop: () => { stopping = true; setImmediate(() => process.exit(0)); return timeReport(world, boards); },
  };
  const lines = createInterface({ input: process.stdin });
  lines.on('line', async (line) => {
    if (!line.trim()) return;
    let msg = {};
    try {
      msg = JSON.parse(line);
      const [prefix, command] = String(msg.cmd).split('.', 2);
      const plugin = command ? controls.get(prefix) : null;
      const handler = plugin ? (m) => plugin.control(command, m) : handlers[msg.cmd];
      if (!handler) throw new Error(`unknown command ${msg.cmd}`);
      send({ id: msg.id, ok: true, ...(await handler(msg)) });
    } catch (error) {
      send({ id: msg.id, ok: false, error: String(error?.message ?? error) });
    }
  });
  lines.on('close', () => process.exit(0)); // the controller went away
  send({ event: 'ready', boards: [...boards.keys()], ...timeReport(world, boards) });
  kick();
}

function boardNamed(boards, name) {
  const board = name == null ? boards.values().next().value : boards.get(name);
  if (!board) throw new Error(`no board ${name}`);
  return board;
}

function connectUsb(board, fd) {
  const socket = new net.Socket({ fd, readable: true, writable: true });
  socket.on('data', (chunk) => board.usbWrite(chunk));
  socket.on('error', () => {});
  board.onUsb((buffer) => socket.write(buffer));
}

main().catch((error) => {
  process.stderr.write(`${error.stack ?? error}\n`);
  process.exit(1);
});
