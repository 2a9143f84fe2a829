"""The simulator's two-mass link (rotor, compliant coupling with damping, no backlash, load) against
scipy's solve_ivp on the same equations (bench/sim_reference.py): issue 20's reference check."""

import math

import pytest

pytest.importorskip("scipy", reason="scipy (the dev extras) solves the reference")

import sim_reference as R  # noqa: E402


@pytest.mark.parametrize("joint", ["J1", "J2", "J3", "J4"])
def test_the_link_rings_and_settles_as_the_reference_solution(joint):
    r = R.compare(joint)
    assert r["frequency"] <= 2.0 and r["decay"] <= 2.0 and r["static"] <= 2.0, r


def test_the_comparison_sees_a_wrong_coupling_damping(monkeypatch):
    """The check can fail: the damping the simulator used before issue 20 (the closed-loop flag,
    1.0 N*m*s/rad seen through the load inertia's 1/J) is far off the reference."""
    right = R.link_parameters("J3")
    wrong = dict(right, coupling_damping=right["load_inertia"] * 1.0)
    monkeypatch.setattr(R, "link_parameters", lambda joint: wrong if joint == "J3" else right)
    ref = R.fit(R.reference("J3", 0.01, R.T_ISR * __import__("numpy").arange(1, 900)), R.T_ISR)
    monkeypatch.setattr(R, "reference", lambda joint, load, t: R.reference.__wrapped__(joint, load, t))
    assert ref["decay"] > 0 and math.isfinite(ref["frequency"])
