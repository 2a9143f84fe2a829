"""The simulator's two-mass link (rotor, compliant coupling with damping, no backlash, load) against
scipy's solve_ivp on the same equations (bench/sim_reference.py): issue 20's reference check."""

import pytest

pytest.importorskip("scipy", reason="scipy (the dev extras) solves the reference")

import sim_reference as R  # noqa: E402


@pytest.mark.parametrize("joint", ["J1", "J2", "J3", "J4"])
def test_the_link_rings_and_settles_as_the_reference_solution(joint):
    r = R.compare(joint)
    assert r["frequency"] <= 2.0 and r["decay"] <= 2.0 and r["static"] <= 2.0, r


def test_the_comparison_sees_the_damping_the_simulator_had_before():
    """Before issue 20 the coupling damping was the closed-loop flag: 0 with the loop off."""
    r = R.compare("J3", coupling_damping=0.0)
    assert r["decay"] > 50.0, r
    stiff = R.compare("J3", coupling_stiffness=1.1 * R.link_parameters("J3")["coupling_stiffness"])
    assert stiff["frequency"] > 2.0 and stiff["static"] > 2.0, stiff
