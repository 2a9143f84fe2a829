"""The TMC5130 ramp generator model (joint.sim.ramp) and the uStepper velocity estimator (joint.motion.velocity)."""

from joint.sim.ramp import Ramp, POSITIONING, VELOCITY_POS, VELOCITY_NEG, HOLD
from joint.motion.velocity import VelocityEstimator

V = 25588.6  # usteps/s: 100 fs/s through the library's VMAX scaling
A = 512227.0  # usteps/s^2: 2000 fs/s^2 through the AMAX scaling


def _ramp(vmax=V, amax=A, dmax=A):
    r = Ramp()
    r.vmax, r.amax, r.dmax = vmax, amax, dmax
    return r


def _run(r, seconds, dt):
    """Step until `seconds`; returns the time at which position_reached() first held (or None)."""
    t = 0.0
    reached = None
    while t < seconds - 1e-12:
        r.step(dt)
        t += dt
        if reached is None and r.position_reached():
            reached = t
    return reached


def test_trapezoid_lands_exactly_on_time():
    r = _ramp()
    r.xtarget = 51200
    reached = _run(r, 3.0, 0.0001)
    expected = 51200 / V + V / A  # cruise time plus one ramp time (two half ramps)
    assert abs(reached - expected) < 0.0002
    assert r.x == 51200.0 and r.v == 0.0 and r.xactual() == 51200


def test_result_does_not_depend_on_step_size():
    ends = []
    for dt, n in ((0.7, 1), (0.7, 2), (0.01, 140), (0.00064857, 2000)):
        r = _ramp()
        r.xtarget = 30000
        for _ in range(n):
            r.step(dt)
        ends.append((r.x, r.v))
    assert ends[0][1] == V
    assert abs(ends[1][0] - 30000) < 1e-9 and ends[1][1] == 0.0, "landed within the second step"
    for x, v in ends[2:]:
        assert abs(x - ends[1][0]) < 1e-6 and v == 0.0


def test_short_move_is_a_triangle():
    r = _ramp()
    r.xtarget = 1000  # shorter than the 1278 usteps of a full ramp up and down
    peak = 0.0
    t = 0.0
    while not r.position_reached():
        r.step(0.0001)
        t += 0.0001
        peak = max(peak, r.v)
    assert abs(peak - (A * 1000) ** 0.5) < 60.0
    assert abs(t - 2 * (1000 / A) ** 0.5) < 0.0003
    assert r.x == 1000.0


def test_target_behind_the_motion_brakes_reverses_and_returns():
    r = _ramp()
    r.xtarget = 100000
    r.step(0.5)
    assert r.v == V
    x_at_reversal_cmd = r.x
    r.xtarget = int(x_at_reversal_cmd) - 1000
    furthest = r.x
    for _ in range(20000):
        r.step(0.0001)
        furthest = max(furthest, r.x)
        if r.position_reached():
            break
    assert r.position_reached() and r.x == r.xtarget
    overshoot = furthest - x_at_reversal_cmd
    assert abs(overshoot - V * V / (2 * A)) < 1.0, "braked at DMAX before reversing"


def test_relabel_in_positioning_mode_keeps_going_toward_the_target():
    r = _ramp()
    r.xtarget = 20000
    r.step(0.2)
    v = r.v
    r.set_position(r.x - 5000)  # the closed loop found the rotor 5000 usteps behind
    assert r.v == v, "a relabel does not touch the velocity"
    reached = _run(r, 2.0, 0.001)
    assert reached is not None and r.x == 20000.0
    assert reached > 0.6, "the extra 5000 usteps took time"


def test_velocity_mode_uses_amax_both_ways_and_ignores_dmax():
    r = _ramp(dmax=A / 100)
    r.mode = VELOCITY_POS
    r.step(V / A)
    assert abs(r.v - V) < 1e-6
    r.vmax = 0.0
    r.step(V / A + 1e-9)
    assert r.v == 0.0, "decelerated at AMAX, not DMAX"
    r.vmax = V
    r.mode = VELOCITY_NEG
    r.step(1.0)
    assert r.v == -V


def test_lowering_vmax_in_positioning_brakes_at_dmax():
    r = _ramp(dmax=A / 2)
    r.xtarget = 10 ** 6
    r.step(0.5)
    r.vmax = V / 2
    r.step(0.25 * V / A)
    assert abs(r.v - (V - 0.25 * V / 2)) < 1e-6, "decelerating at DMAX"
    r.step(1.0)
    assert r.v == V / 2


def test_hold_mode_keeps_velocity_and_zero_vmax_parks():
    r = _ramp()
    r.mode = VELOCITY_POS
    r.step(0.2)
    r.mode = HOLD
    x = r.x
    r.step(0.1)
    assert r.v == V and abs(r.x - x - 0.1 * V) < 1e-6
    r = _ramp(vmax=0.0)
    r.mode = POSITIONING
    r.xtarget = 500
    r.step(1.0)
    assert r.x == 0.0 and not r.position_reached(), "VMAX 0: the target is never approached"


def test_step_returns_the_distance_travelled_not_relabels():
    r = _ramp()
    r.mode = VELOCITY_POS
    moved = r.step(0.2)
    r.set_position(0)
    moved += r.step(0.2)
    assert abs(moved - (0.4 * V - V * V / (2 * A))) < 1e-6


def test_estimator_step_response_matches_the_library_filter():
    rate = 1541.85
    est = VelocityEstimator(rate)
    v = 10000.0
    crossings = {}
    peak = 0.0
    for k in range(1, int(0.6 * rate)):
        out = est.update(v * k / rate)
        peak = max(peak, out)
        for frac in (0.1, 0.5, 0.9):
            if frac not in crossings and out >= frac * v:
                crossings[frac] = k / rate
    assert abs(crossings[0.1] - 0.013) < 0.002
    assert abs(crossings[0.5] - 0.047) < 0.002
    assert abs(crossings[0.9] - 0.134) < 0.003
    assert peak <= v * 1.0001, "overdamped: no overshoot"
    est.reset(123.0)
    assert est.value == 0.0 and est.update(123.0) == 0.0
