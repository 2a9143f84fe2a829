// The TMC2209 fake on UART1 behaves as the datasheet says, seen from MicroPython's machine.UART.
import assert from 'node:assert/strict';
import { test } from 'node:test';
import { Board, World } from '../src/board.mjs';
import { JointDevices } from '../src/joint-devices.mjs';
import { tmcCrc } from '../src/tmc2209.mjs';
import { skipNoBinaries } from './helpers.mjs';
import { RawRepl } from './repl.mjs';

// On the board: datagrams with a CRC computed the other way round (CRC-8/ATM on bit-reversed
// bytes), so the fake's CRC is checked against an independent derivation.
const HELPERS = `
import machine, time
u = machine.UART(1, 115200, tx=machine.Pin(8), rx=machine.Pin(9), timeout=20, timeout_char=5)
def rev(b):
    r = 0
    for _ in range(8):
        r = (r << 1) | (b & 1); b >>= 1
    return r
def crc(data):
    c = 0
    for b in data:
        c ^= rev(b)
        for _ in range(8):
            c = ((c << 1) ^ 7) & 0xff if c & 0x80 else (c << 1) & 0xff
    return c
def req(reg, node=0):
    d = bytes([5, node, reg]); return d + bytes([crc(d)])
def wr(reg, v, node=0, bad=False):
    d = bytes([5, node, reg | 0x80, v >> 24 & 255, v >> 16 & 255, v >> 8 & 255, v & 255])
    return d + bytes([crc(d) ^ (1 if bad else 0)])
def xfer(data, n):
    while u.any(): u.read()
    u.write(data)
    got = b''
    t = time.ticks_ms()
    while len(got) < n and time.ticks_diff(time.ticks_ms(), t) < 20:
        got += u.read() or b''
    return got
def read(reg, node=0):
    r = xfer(req(reg, node), 12)
    assert r[:4] == req(reg, node), r
    r = r[4:]
    if len(r) < 8: return None
    assert r[0] == 5 and r[1] == 0xff and r[2] == reg, r
    assert crc(r[:7]) == r[7], ('crc', r)
    return int.from_bytes(r[3:7], 'big')
`;

function setup() {
  const board = new Board();
  const world = new World();
  world.add(board);
  const devices = new JointDevices(board);
  const repl = new RawRepl(world, board).start();
  repl.exec(HELPERS);
  return { board, devices, repl };
}

test('the CRC matches a datagram the datasheet way (LSB first, poly 0x07)', () => {
  // reference: CRC-8/ATM over bit-reversed bytes, derived independently here
  const rev = (b) => { let r = 0; for (let i = 0; i < 8; i++) { r = (r << 1) | (b & 1); b >>= 1; } return r; };
  const ref = (bytes) => {
    let c = 0;
    for (const b of bytes) {
      c ^= rev(b);
      for (let i = 0; i < 8; i++) c = c & 0x80 ? ((c << 1) ^ 7) & 0xff : (c << 1) & 0xff;
    }
    return c;
  };
  for (const d of [[5, 0, 6], [5, 0xff, 0x6c, 0x10, 0, 0, 0x53], [5, 3, 0x90, 1, 2, 3, 4], [0xff, 0xff, 0xff]]) {
    assert.equal(tmcCrc(d), ref(d));
  }
});

test('reads: IOIN VERSION 0x21, reset values, replies only to its node', { skip: skipNoBinaries }, () => {
  const { repl } = setup();
  const out = repl.exec(`
print(hex(read(6)), hex(read(0)), hex(read(0x6c)), hex(read(0x70)), read(2), read(1))
print(read(6, node=1))
machine.Pin(12, machine.Pin.OUT, value=1)
print(read(6) & 1)
`);
  const [line1, line2, line3] = out.trim().split(/\r?\n/);
  const [ioin, gconf, chop, pwm, ifcnt, gstat] = line1.split(' ');
  assert.equal(Number(ioin) >>> 24, 0x21);
  assert.equal(Number(ioin) & 1, 0, 'ENN reads low: GP12 undriven, the pad pulls it down');
  assert.equal(line3, '1', 'ENN reads high: GP12 driven high');
  assert.deepEqual([gconf, chop, pwm, ifcnt, gstat], ['0x101', '0x10000053', '0xc10d0024', '0', '1']);
  assert.equal(line2, 'None');
});

test('writes: IFCNT counts valid writes only; registers read back; GSTAT clears by writing 1', { skip: skipNoBinaries }, () => {
  const { repl, devices } = setup();
  const out = repl.exec(`
xfer(wr(0x00, 0x1c0), 8)
xfer(wr(0x10, 0x00061f08), 8)
xfer(wr(0x6c, 0x15000053), 8)
xfer(wr(0x00, 0x1c8, bad=True), 8)
xfer(wr(0x00, 0x1c8, node=2), 8)
xfer(wr(0x01, 1), 8)
print(read(2), hex(read(0)), hex(read(0x6c)), read(1), read(0x10))
`);
  assert.equal(out.trim(), '4 0x1c0 0x15000053 0 0');
  const s = devices.driver.state();
  assert.equal(s.ifcnt, 4);
  assert.deepEqual([s.ihold, s.irun, s.iholddelay], [8, 31, 6]);
  assert.equal(s.microsteps, 256 >> 5);
  assert.deepEqual(s.writes.map(([reg]) => reg), ['GCONF', 'IHOLD_IRUN', 'CHOPCONF', 'GSTAT']);
});

test('reply timing: echo at the baud rate, reply after SENDDELAY bit times', { skip: skipNoBinaries }, () => {
  const { board, repl } = setup();
  const uart = board.rp2040.uart[1];
  const times = [];
  const feed = uart.feedByte.bind(uart);
  uart.feedByte = (b) => { times.push(board.nanos); feed(b); };
  repl.exec('read(6)');
  const bit = 1e9 * 16 * uart.baudDivider / board.rp2040.clkPeri;
  assert.equal(times.length, 12);
  const gaps = times.slice(1).map((t, i) => (t - times[i]) / bit);
  for (const g of [...gaps.slice(0, 3), ...gaps.slice(4)]) assert.ok(Math.abs(g - 10) < 0.01, `gap ${g} bits`);
  assert.ok(Math.abs(gaps[3] - (8 + 10)) < 0.01, `request end to first reply byte ${gaps[3]} bits`);
  times.length = 0;
  repl.exec('xfer(wr(0x03, 4 << 8), 8)\nread(6)'); // SENDDELAY 4: 5 * 8 bit times
  const g2 = (times[12] - times[11]) / bit;
  assert.ok(Math.abs(g2 - (40 + 10)) < 0.01, `${g2} bits`);
});

test('faults: a corrupt reply, a missing reply, an ignored write', { skip: skipNoBinaries }, () => {
  const { repl, devices } = setup();
  devices.control('driver_faults', { badCrc: 1 });
  assert.match(repl.exec('try:\n    read(6)\nexcept AssertionError as e:\n    print(e)'), /crc/);
  devices.control('driver_faults', { silent: 1 });
  assert.equal(repl.exec('print(read(6))').trim(), 'None');
  devices.control('driver_faults', { ignoreWrites: 1 });
  assert.equal(repl.exec('xfer(wr(0, 0x1c0), 8)\nxfer(wr(0, 0x1c0), 8)\nprint(read(2))').trim(), '1');
  devices.control('driver_faults', { absent: true });
  assert.equal(repl.exec('print(len(xfer(req(6), 12)))').trim(), '4', 'only the echo');
});
