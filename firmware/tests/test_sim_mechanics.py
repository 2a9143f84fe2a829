"""The arm's mechanics in the simulated stepper: load inertia behind a compliant transmission with
backlash, gravity on J2, end stops stable at any stiffness and damping, the encoders' resolution."""

import math

from joint.sim import mechanics as M
from joint.sim.clock import VirtualClock
from joint.sim.stepper import SimStepper


def _motor(current=20, seed=1, **kw):
    clock = VirtualClock()
    m = SimStepper(clock, seed=seed, **kw)
    m.begin()
    m.enable_closed_loop()
    m.set_control_threshold(15)
    m.set_current(current)
    m.set_hold_current(current)
    return clock, m


def _run(clock, m, seconds, step_us=1000, each=None):
    for _ in range(int(seconds * 1e6 / step_us + 0.5)):
        clock.advance(step_us)
        m.update()
        if each is not None:
            each()


def _rpm(m):
    return m._rotor_speed * 60.0 / 51200.0


def test_end_stops_are_stable_at_any_stiffness_and_damping():
    # Explicit damping used to throw the rotor back at up to 1500 rpm from 0.5 N*m*s/rad on.
    for stiffness in (20.0, 2e6):
        for damping in (0.0, 0.5, 500.0):
            clock, m = _motor(wall_stiffness=stiffness, wall_damping=damping)
            m.set_end_stops(high_deg=90.0)
            m.set_max_acceleration(2000)
            m.set_rpm(200.0)
            seen = {"back": 0.0, "deep": 0.0}

            def watch():
                seen["back"] = min(seen["back"], _rpm(m))
                seen["deep"] = max(seen["deep"], m.rotor_angle() - 90.0)
            _run(clock, m, 0.6, each=watch)
            assert seen["back"] > -200.0, (stiffness, damping, seen)
            assert seen["deep"] < max(0.3, 2 * 0.45 / stiffness * 57.3), (stiffness, damping, seen)
            assert math.isfinite(m.rotor_angle()) and m.rotor_angle() > 80.0


def test_a_link_hits_its_stop_through_the_transmission_without_bouncing_off():
    for joint in ("J1", "J2", "J3", "J4"):
        for kind in ("rigid", "soft"):
            k, c = M.stop_stiffness(joint, kind)
            back = []
            for damping in (c, 1e4 * c + 100.0):
                clock, m = _motor(**M.stepper_kwargs(joint))
                m.set_max_acceleration(2000)
                m.add_obstacle(60.0, 1, stiffness=k, damping=damping)
                m.set_rpm(60.0)
                seen = [0.0]

                def watch():
                    seen[0] = min(seen[0], m._load_speed * 60.0 / 51200.0)
                _run(clock, m, 0.8, 2000, each=watch)
                back.append(seen[0])
                # Static penetration: at most the motor's torque over the stop's stiffness.
                assert m.load_angle() < 60.0 + 0.45 / k * 57.3 + 0.5, (joint, kind, m.load_angle())
            # A springy obstacle may return the link (and the rotor's pole slips shake it), but
            # more damping never throws it back harder.
            assert back[1] > back[0] - 20.0, (joint, kind, back)


def test_backlash_lets_the_rotor_turn_before_the_load_follows():
    kw = M.stepper_kwargs("J4")
    kw.update(backlash=4.0, enc_sigma=0.0, enc_harmonics=(0.0, 0.0))
    clock, m = _motor(**kw)
    m.move_angle(20.0)
    _run(clock, m, 1.0)
    load_fwd = m.load_angle()
    m.move_angle(-3.0)
    _run(clock, m, 1.0)
    assert abs(m.rotor_angle() - 17.0) < 0.2
    assert abs(m.load_angle() - load_fwd) < 0.3, "the play swallowed a 3 degree reversal"
    m.move_angle(-3.0)
    _run(clock, m, 1.0)
    assert m.load_angle() < load_fwd - 1.5, "through the play, the load follows"


def test_the_transmission_deflects_under_a_load_on_the_link():
    kw = M.stepper_kwargs("J1")
    kw.update(backlash=0.0)
    clock, m = _motor(current=40, **kw)
    _run(clock, m, 0.5)
    m.set_load_torque(0.02)
    _run(clock, m, 1.0)
    twist = m.rotor_angle() - m.load_angle()
    expected = 0.02 / kw["coupling_stiffness"] * 57.2958
    assert abs(twist - expected) < 0.1 * expected + 0.05, (twist, expected)


def test_a_loaded_j2_falls_through_its_lead_screw_when_the_coils_are_open():
    drift = {}
    for payload in (0.0, 1.0):
        clock, m = _motor(current=40, **M.stepper_kwargs("J2", payload_kg=payload))
        m.set_brake_mode(0)
        m.set_current(0)
        _run(clock, m, 3.0)
        drift[payload] = m.load_angle()
    assert drift[0.0] < 10.0, "the bare arm is held by screw and rotor friction"
    assert drift[1.0] > 360.0, "with a payload it back-drives the screw (toward the bottom: +motor)"
    clock, m = _motor(current=40, **M.stepper_kwargs("J2", payload_kg=1.0))
    _run(clock, m, 1.5, 2000)
    assert abs(m.load_angle()) < 5.0, "energized, the hold current keeps it"


def test_as5600_resolution_is_a_twelfth_bit():
    kw = M.stepper_kwargs("J4", encoder="as5600")
    kw.update(enc_sigma=0.0, enc_harmonics=(0.0, 0.0))
    clock, m = _motor(**kw)
    seen = set()
    m.move_angle(3.0)
    _run(clock, m, 0.5, each=lambda: seen.add(round(m.angle_moved() / (360.0 / 4096), 6)))
    assert all(v == int(v) for v in seen), "only whole counts of 360/4096 degrees"
    assert m.pid_error() % 12.5 == 0.0 or abs(m.pid_error()) < 15.0


def test_default_arm_moves_at_the_shipped_limits_without_losing_steps():
    # The original parameters (20 % current; J3 14 rad/s^2 to 5 rad/s) run on the real arm.
    for (joint, n, acc, vel), seed in zip((("J1", 35, 2.0, 1.0), ("J3", 24, 14.0, 5.0), ("J4", 12, 30.0, 10.0)),
                                          (1, 2, 1)):
        clock, m = _motor(seed=seed, **M.stepper_kwargs(joint))
        m.set_max_acceleration(math.degrees(acc * n) * 200 / 360)
        m.set_max_deceleration(math.degrees(acc * n) * 200 / 360)
        m.set_max_velocity(math.degrees(vel * n) * 200 / 360)
        target = math.degrees(2.0 * n)
        m.move_to_angle(target)
        _run(clock, m, 2.0 / vel + vel / acc + 1.0, 5000)
        assert abs(m.angle_moved() - target) < 0.5, (joint, m.angle_moved())
        assert abs(m.load_angle() - target) < M.position_error_bound_deg(joint, 20), (joint, m.load_angle())
