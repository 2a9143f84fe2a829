// The rotor model: follows the driver, held back by end stops, slips whole electrical periods.
import assert from 'node:assert/strict';
import { test } from 'node:test';
import { AS5600 } from '../src/as5600.mjs';
import { Rotor } from '../src/rotor.mjs';

function driver() {
  const d = { position: 0, onStep: null };
  d.step = (n) => {
    for (let i = 0; i < Math.abs(n); i++) {
      d.position += Math.sign(n);
      d.onStep(d.position, i);
    }
  };
  return d;
}

test('the rotor follows the driver and the encoder sees 4096 counts a turn', () => {
  const d = driver();
  const rotor = new Rotor(d, { offsetCounts: 1000 });
  d.step(51200 / 4);
  assert.equal(rotor.position, 12800);
  const enc = new AS5600(() => rotor.counts());
  assert.equal(enc.rawAngle(), 2024);
  d.step(-51200);
  assert.equal(enc.rawAngle(), 2024); // a whole turn back, wrapped
});

test('an end stop pins the rotor; running on loses whole electrical periods', () => {
  const d = driver();
  const rotor = new Rotor(d);
  rotor.setStops(null, 10); // 10 deg = 1422.2 usteps
  d.step(1422);
  assert.equal(rotor.position, 1422);
  d.step(300); // pushing on, less than half an electrical period: pinned
  assert.equal(rotor.position, rotor.high);
  d.step(1000); // more: it falls back by a period (4 full steps) and comes forward again
  assert.equal(rotor.slip, 1024);
  assert.ok(rotor.position <= rotor.high && rotor.position > rotor.high - 512);
  d.step(-(2722 - 1024)); // the driver back at 1024: the rotor, one period behind, at 0
  assert.equal(rotor.position, d.position - 1024);
  assert.ok(rotor.blockedSteps > 0);
});

test('taking a stop away lets the rotor snap to the field', () => {
  const d = driver();
  const rotor = new Rotor(d);
  rotor.setStops(-1, null);
  d.step(-400);
  assert.equal(rotor.position, rotor.low);
  rotor.setStops(null, null);
  assert.equal(rotor.position, -400);
});

test('encoder noise is bounded and repeatable', () => {
  const a = new AS5600(() => 1000, { seed: 7 });
  const b = new AS5600(() => 1000, { seed: 7 });
  a.noise = b.noise = 2;
  const xs = Array.from({ length: 200 }, () => a.rawAngle());
  assert.deepEqual(xs, Array.from({ length: 200 }, () => b.rawAngle()));
  assert.ok(xs.every((x) => Math.abs(x - 1000) <= 2));
  assert.ok(new Set(xs).size > 1);
});
