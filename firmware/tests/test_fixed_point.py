"""Fixed-point arithmetic of the 1 kHz path (joint.motion.fixed) and the integer ramp and estimator.

The integer versions are judged against the exact float models the simulator uses (joint.sim.ramp.Ramp,
joint.motion.velocity.VelocityEstimator) and against struct's float32 encoding, on both interpreters.
"""

import struct

from joint.motion.fixed import LIMIT, f32_to_q, i32, muldiv, store_q, to_q
from joint.sim.ramp import HOLD, POSITIONING, VELOCITY_NEG, VELOCITY_POS, Ramp
from joint.motion.tickramp import TickRamp
from joint.motion.velocity import FixedVelocityEstimator, VelocityEstimator
from harness import Xorshift


def _f32(x):
    return struct.unpack("<f", struct.pack("<f", x))[0]


def test_float32_payloads_decode_to_rounded_fixed_point():
    rng = Xorshift(7)
    for _ in range(3000):
        x = _f32((rng.below(2000001) - 1000000) / (1 + rng.below(1000)))
        buf = struct.pack("<f", x)
        for q in (0, 4, 12, 16):
            scaled = abs(x) * (1 << q)
            want = min(int(scaled + 0.5), LIMIT)
            assert f32_to_q(buf, 0, q) == (-want if x < 0 else want), (x, q)
    assert f32_to_q(struct.pack("<f", 1e30), 0, 16) == LIMIT  # saturates, never a long int
    assert f32_to_q(struct.pack("<f", -1e30), 0, 16) == -LIMIT
    assert f32_to_q(struct.pack("<f", 1e-30), 0, 16) == 0
    assert f32_to_q(bytes(4), 0, 16) == 0


def test_fixed_point_packs_the_same_float32_bytes_as_struct():
    rng = Xorshift(11)
    edges = [0, 1, -1, (1 << 24) - 1, 1 << 24, (1 << 24) + 1, (1 << 24) + 3, (1 << 25) + 2,
             (1 << 25) + 6, (1 << 26) - 1, LIMIT, -LIMIT, 0x2AAAAAAA, 0x3FFFFFC0, 0x3FFFFFE0]
    for i in range(4000):
        if i < len(edges):
            n = edges[i]
        else:
            bits = 1 + rng.below(30)  # every magnitude up to LIMIT, rounding included
            n = rng.below(1 << bits) - (1 << (bits - 1))
        for q in (0, 4, 12, 16):
            buf = bytearray(4)
            store_q(buf, n, q)
            assert bytes(buf) == struct.pack("<f", n / (1 << q)), (n, q)


def test_int32_payloads_and_overflow_safe_scaling():
    for v in (0, 1, -1, 123456789, -98765, (1 << 30) - 1, -(1 << 30), (1 << 31) - 1, -(1 << 31)):
        assert i32(struct.pack("<i", v), 0) == v
    rng = Xorshift(3)
    for _ in range(2000):
        a = rng.below(1 << 30)
        num, den = 1 + rng.below(3000), 1 + rng.below(3000)
        assert muldiv(a, num, den) == a * num // den
    assert to_q(-2.5, 0) == -3 and to_q(2.5, 0) == 3 and to_q(0.25, 12) == 1024


def _tick_ramp(vmax, amax, dmax, rate=1000):
    """A TickRamp with Ramp's usteps/s and usteps/s^2 settings."""
    r = TickRamp()
    r.vmax = to_q(vmax / rate, 16)
    r.amax = to_q(amax / rate / rate, 16)
    r.dmax = to_q(dmax / rate / rate, 16)
    return r


def _follow(target, vmax, amax, dmax, ms, v0=0.0, mode=POSITIONING):
    """Run both ramps 1 ms at a time; (largest position gap, ms to arrive exact, ms integer)."""
    exact = Ramp()
    exact.vmax, exact.amax, exact.dmax = vmax, amax, dmax
    exact.xtarget, exact.mode, exact.v = target, mode, v0
    ticks = _tick_ramp(vmax, amax, dmax)
    ticks.xtarget, ticks.mode, ticks.v = target, mode, to_q(v0 / 1000, 16)
    gap = 0.0
    arrived = [None, None]
    for ms_now in range(1, ms + 1):
        exact.step(0.001)
        ticks.tick()
        gap = max(gap, abs(exact.x - (ticks.x + ticks.xf / 65536)))
        if arrived[0] is None and exact.position_reached():
            arrived[0] = ms_now
        if arrived[1] is None and ticks.position_reached():
            arrived[1] = ms_now
    return gap, arrived[0], arrived[1], ticks


def test_integer_ramp_follows_the_exact_ramp_and_lands_on_target():
    cases = (
        (51200, 25588.6, 512227.0, 512227.0, 2500, 0.0),  # the library's default trapezoid
        (51200, 250000.0, 30000.0, 20000.0, 4000, 0.0),  # a triangle with dmax < amax
        (300, 25588.6, 512227.0, 512227.0, 200, 0.0),  # a short move
        (-5000, 25588.6, 51222.0, 51222.0, 2000, 20000.0),  # target behind: brake, reverse
        (1000000, 285000.0, 102400.0, 102400.0, 7000, 0.0),  # J1 at full speed
    )
    for target, vmax, amax, dmax, ms, v0 in cases:
        gap, exact_ms, tick_ms, r = _follow(target, vmax, amax, dmax, ms, v0)
        assert r.position_reached() and r.x == target and r.xactual() == target
        assert gap < vmax / 1000 + 20, (target, gap)  # usteps: one tick of travel, Q16 rounding
        assert abs(exact_ms - tick_ms) <= max(10, exact_ms // 100), (target, exact_ms, tick_ms)


def test_integer_ramp_velocity_modes_and_hold():
    gap, _, _, r = _follow(0, 285000.0, 102400.0, 102400.0, 3000, mode=VELOCITY_POS)
    assert r.v == r.vmax and gap < 60
    r.mode = VELOCITY_NEG
    for _ in range(5600):  # 2 x 2.783 s at 102 400 usteps/s^2: through zero to -vmax
        r.tick()
    assert r.v == -r.vmax
    r.mode = HOLD
    x = r.x
    r.tick()
    assert r.v == -r.vmax and x - r.x in (284, 285, 286)
    r.vmax = 0
    r.mode = POSITIONING
    r.xtarget = r.x + 1000
    r.v = 0
    r.tick()
    assert r.v == 0 and not r.position_reached(), "vmax 0 parks short of the target"


def test_integer_estimator_tracks_the_float_filter():
    exact = VelocityEstimator(1000)
    fixed = FixedVelocityEstimator(1000)
    worst = 0.0
    count = 0
    for k in range(1, 2500):
        count = 20 * k + (30 if (k // 40) % 2 else -30)  # 20 000 counts/s with a square wobble
        a = exact.update(count)
        b = fixed.update(count) / 256
        worst = max(worst, abs(a - b))
    assert worst < 0.002 * 20000 + 5, worst
    fixed.reset(count)
    assert fixed.value == 0 and fixed.update(count) == 0
