// Several boards in one process, stepped together; the same inputs at the same emulated times give
// the same run, cycle for cycle; the event queue runs callbacks at their exact cycle.
import assert from 'node:assert/strict';
import { test } from 'node:test';
import { Board, World } from '../src/board.mjs';
import { skipNoBinaries, usbText } from './helpers.mjs';

test('two boards step together and run identically from identical inputs', { skip: skipNoBinaries }, () => {
  const world = new World({ quantumNanos: 5_000 });
  const boards = [world.add(new Board({ name: 'a' })), world.add(new Board({ name: 'b' }))];
  const usb = boards.map(usbText);
  let maxDrift = 0;
  world.onStep(() => { maxDrift = Math.max(maxDrift, Math.abs(boards[0].nanos - boards[1].nanos)); });
  assert.ok(world.runUntilTrue(() => boards.every((b) => b.usbConnected), 2e9));
  for (const b of boards) b.usbWrite(Buffer.from('\r'));
  assert.ok(world.runUntilTrue(() => usb.every((u) => u.text.includes('>>> ')), 1e9));
  const answered = [null, null];
  for (const b of boards) b.usbWrite(Buffer.from('import time; print(time.ticks_us() > 0, sum(range(1000)))\r'));
  world.runUntilTrue(() => {
    usb.forEach((u, i) => { if (answered[i] === null && u.text.includes('499500')) answered[i] = boards[i].cycles; });
    return answered.every((c) => c !== null);
  }, 1e9);
  assert.ok(answered[0] > 0);
  assert.equal(answered[0], answered[1]);
  assert.equal(usb[0].text, usb[1].text);
  assert.ok(maxDrift < 5_000 + 1000, `boards drifted ${maxDrift} ns apart`);
});

test('the event queue runs a callback at its exact cycle', { skip: skipNoBinaries }, () => {
  const world = new World();
  const board = world.add(new Board());
  world.runFor(1e6);
  const seen = [];
  const due = board.cycles + 12_345;
  board.atCycle(due, (b) => seen.push(b.cycles));
  const cancelled = board.afterCycles(100, () => seen.push('cancelled'));
  cancelled.cancel();
  world.runFor(1e6);
  assert.deepEqual(seen, [due]);
});
