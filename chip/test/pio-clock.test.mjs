// The PIO runs on clk_sys through CLKDIV (RP2040 datasheet 3.5.5), delay cycles included.
import assert from 'node:assert/strict';
import { test } from 'node:test';
import { Board, World } from '../src/board.mjs';
import { skipNoBinaries } from './helpers.mjs';
import { RawRepl } from './repl.mjs';

const TOGGLE = `
import rp2, machine, time
def busy_us(us):  # not sleep_ms: it is the PIO we time, not the timer
    t = time.ticks_us()
    while time.ticks_diff(time.ticks_us(), t) < us:
        pass
@rp2.asm_pio(set_init=rp2.PIO.OUT_LOW)
def toggle():
    set(pins, 1) [31]
    set(pins, 0) [31]
`;

function setup() {
  const board = new Board();
  const world = new World();
  world.add(board);
  const edges = [];
  board.rp2040.gpio[15].addListener((value) => edges.push({ t: board.pio.nanos, value }));
  return { board, world, edges, repl: new RawRepl(world, board).start() };
}

function risingPeriods(edges) {
  const rises = edges.filter((e) => e.value === 1).map((e) => e.t);
  return rises.slice(1).map((t, i) => t - rises[i]);
}

test('an integer divider: 64 PIO cycles per period at clk_sys / 62', { skip: skipNoBinaries }, () => {
  const { repl, edges } = setup();
  repl.exec(`${TOGGLE}
sm = rp2.StateMachine(0, toggle, freq=125_000_000 // 62, set_base=machine.Pin(15))
print(hex(machine.mem32[0x502000c8]))
sm.active(1)
busy_us(3000)
sm.active(0)
`);
  const periods = risingPeriods(edges);
  assert.ok(periods.length > 50, `${periods.length} periods`);
  assert.deepEqual([...new Set(periods)], [64 * 62 * 8]); // ns: 64 enables x 62 cycles x 8 ns
});

test('a fractional divider: periods of floor/ceil cycles averaging INT + FRAC/256', { skip: skipNoBinaries }, () => {
  const { repl, edges } = setup();
  const out = repl.exec(`${TOGGLE}
sm = rp2.StateMachine(0, toggle, freq=2_000_000, set_base=machine.Pin(15))
print(hex(machine.mem32[0x502000c8]))
sm.active(1)
busy_us(3000)
sm.active(0)
`);
  assert.equal(out.trim(), '0x3e8000'); // 62 + 128/256 = 62.5
  const periods = risingPeriods(edges);
  assert.ok(periods.length > 50);
  assert.deepEqual([...new Set(periods)], [32000]); // 64 x 62.5 cycles = 4000 cycles exactly
  const { repl: r2, edges: e2 } = setup();
  r2.exec(`${TOGGLE}
sm = rp2.StateMachine(0, toggle, freq=125_000_000, set_base=machine.Pin(15))
machine.mem32[0x502000c8] = (3 << 16) | (64 << 8)  # 3.25
sm.active(1)
busy_us(2000)
sm.active(0)
`);
  const p2 = risingPeriods(e2);
  const mean = p2.reduce((a, b) => a + b, 0) / p2.length;
  assert.ok(Math.abs(mean - 64 * 3.25 * 8) < 1, `mean ${mean}`);
  for (const p of p2) assert.ok(p >= 64 * 3 * 8 && p <= 64 * 4 * 8, `period ${p}`);
});

test('a disabled state machine does not run', { skip: skipNoBinaries }, () => {
  const { repl, edges } = setup();
  repl.exec(`${TOGGLE}
sm = rp2.StateMachine(0, toggle, freq=2_000_000, set_base=machine.Pin(15))
sm.active(1)
busy_us(1000)
sm.active(0)
`);
  const n = edges.length;
  assert.ok(n > 10, `${n} edges`);
  repl.exec('busy_us(2000)');
  assert.equal(edges.length, n);
});
