// The AS5600 fake on I2C1 answers as the datasheet says, over a bus that takes its SCL time.
import assert from 'node:assert/strict';
import { test } from 'node:test';
import { Board, World } from '../src/board.mjs';
import { JointDevices } from '../src/joint-devices.mjs';
import { skipNoBinaries } from './helpers.mjs';
import { RawRepl } from './repl.mjs';

function setup(freq = 400000) {
  const board = new Board();
  const world = new World();
  world.add(board);
  const devices = new JointDevices(board, { offsetCounts: 1000 });
  const repl = new RawRepl(world, board).start();
  repl.exec(`import machine, time\ni2c = machine.I2C(1, sda=machine.Pin(6), scl=machine.Pin(7), freq=${freq})\nb2 = bytearray(2)`);
  return { board, devices, repl };
}

const word = (out) => out.trim().split(' ').map(Number);

test('registers: STATUS, RAW ANGLE, ANGLE with ZPOS, CONF read back, pointer rules', { skip: skipNoBinaries }, () => {
  const { repl, devices } = setup();
  assert.equal(repl.exec('print(i2c.readfrom_mem(0x36, 0x0b, 1)[0])').trim(), String(0x20));
  assert.deepEqual(word(repl.exec('r = i2c.readfrom_mem(0x36, 0x0c, 2); a = i2c.readfrom_mem(0x36, 0x0e, 2)\nprint(r[0] << 8 | r[1], a[0] << 8 | a[1])')), [1000, 1000]);
  // RAW ANGLE is re-read without a pointer write; other registers increment the pointer
  assert.deepEqual(word(repl.exec('r = i2c.readfrom(0x36, 4)\nprint(r[0] << 8 | r[1], r[2] << 8 | r[3])')), [1000, 1000]);
  repl.exec('i2c.writeto_mem(0x36, 0x07, bytes([0x03, 0x00]))');
  assert.deepEqual(word(repl.exec('c = i2c.readfrom_mem(0x36, 0x07, 2)\nprint(c[0], c[1])')), [3, 0]);
  assert.equal(devices.encoder.state().conf, 0x0300);
  repl.exec('i2c.writeto_mem(0x36, 0x01, bytes([0x03, 0x00]))'); // ZPOS = 768
  assert.deepEqual(word(repl.exec('r = i2c.readfrom_mem(0x36, 0x0c, 2); a = i2c.readfrom_mem(0x36, 0x0e, 2)\nprint(r[0] << 8 | r[1], a[0] << 8 | a[1])')), [1000, 232]);
  repl.exec('i2c.writeto_mem(0x36, 0x0c, bytes([0, 0]))'); // read-only: ignored
  assert.equal(word(repl.exec('r = i2c.readfrom_mem(0x36, 0x0c, 2)\nprint(r[0] << 8 | r[1])'))[0], 1000);
  devices.encoder.magnet = 'weak';
  assert.equal(repl.exec('print(i2c.readfrom_mem(0x36, 0x0b, 1)[0])').trim(), String(0x30));
});

test('the angle follows the source; a NACK is an OSError on the board', { skip: skipNoBinaries }, () => {
  const { repl, devices } = setup();
  devices.rotor.position = 51200 / 4; // a quarter turn: +1024 counts
  assert.equal(word(repl.exec('i2c.readfrom_mem_into(0x36, 0x0c, b2)\nprint(b2[0] << 8 | b2[1])'))[0], 2024);
  devices.control('encoder_faults', { nack: 1 });
  const nacked = repl.exec('t = time.ticks_us()\ntry:\n    i2c.readfrom_mem_into(0x36, 0x0c, b2)\nexcept OSError as e:\n    print("OSError", e, time.ticks_diff(time.ticks_us(), t))');
  assert.match(nacked, /OSError \[Errno 5\] EIO/); // EIO: the address was not acknowledged
  assert.ok(Number(nacked.trim().split(' ').pop()) < 1000, `${nacked}: an abort, not a timeout`);
  assert.equal(word(repl.exec('i2c.readfrom_mem_into(0x36, 0x0c, b2)\nprint(b2[0] << 8 | b2[1])'))[0], 2024);
});

for (const freq of [100000, 400000]) {
  test(`bus time at ${freq / 1000} kHz: 48 SCL periods for a 2-byte register read`, { skip: skipNoBinaries }, () => {
    const { repl, devices } = setup(freq);
    const bus = devices.encoderBus;
    assert.ok(Math.abs(bus.sclHz - freq) / freq < 0.1, `SCL ${bus.sclHz} Hz`);
    const before = bus.busyNanos;
    const out = repl.exec(`t = time.ticks_us()
for _ in range(20):
    i2c.readfrom_mem_into(0x36, 0x0c, b2)
print(time.ticks_diff(time.ticks_us(), t) / 20)`);
    const wire = (bus.busyNanos - before) / 20 / 1000; // us per read on the wire
    const period = 1e6 / bus.sclHz;
    assert.ok(Math.abs(wire - 48 * period) < 0.01, `${wire} us on the wire, period ${period} us`);
    const call = Number(out.trim());
    assert.ok(call > wire && call < wire + 150, `a call took ${call} us, the wire ${wire} us`);
  });
}
