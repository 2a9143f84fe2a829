"""The simulated joint's two-mass link against an independent solution of the same equations.

The simulator (firmware/joint/sim/stepper.py) integrates, on the ISR grid with its own sub-steps,
ustepper-model.md 8.4 Level 2 with a load behind a compliant transmission (mechanics.py):

    J_r dw_r/dt = T_max sin(50 (phi - th_r)) / (1 + |w_r| / w_corner) - b w_r - k (th_r - th_l) - c (w_r - w_l)
    J_l dw_l/dt = k (th_r - th_l) + c (w_r - w_l) - b_l w_l - T_load

(rad and N*m on the motor side, 50 pole pairs, the field phi held still, no backlash, no dry
friction: those are not smooth and not what this checks). Here scipy's solve_ivp solves the same
equations at tight tolerances, from the same start, for a step of load torque on a powered joint at
rest. Both responses of the load angle are fitted with two damped modes plus an offset; the
figures compared are the dominant mode's natural frequency and decay rate and the static
deflection (the offset), per joint of the arm.

    python bench/sim_reference.py      # safety.sim_reference_error_pct and the figures per joint
"""

from __future__ import annotations

import math
import pathlib
import sys

import numpy as np
from scipy.integrate import solve_ivp

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "firmware"))

from joint.sim import mechanics as M  # noqa: E402
from joint.sim.clock import VirtualClock  # noqa: E402
from joint.sim.stepper import SimStepper  # noqa: E402

POLE_PAIRS = 50
USTEPS_PER_RAD = 51200.0 / (2.0 * math.pi)
CURRENT = {"J1": 20, "J2": 40, "J3": 20, "J4": 20}  # shipped drive current, % (default.toml)
# The torque step, as a fraction of the motor's torque at that current: small enough that the
# response is two clean modes (the magnet's sin and the back-EMF roll-off stay nearly linear).
LOAD_FRACTION = 0.1
SECONDS = 0.6
T_ISR = 1.0 / 1541.85  # s: the library's ISR period, the simulator's grid


def link_parameters(joint: str) -> dict:
    """The arm's link on the motor side without dry friction and backlash (SimStepper kwargs)."""
    kw = M.stepper_kwargs(joint)
    kw.update(coulomb=0.0, load_friction=0.0, backlash=0.0, load_torque=0.0, enc_sigma=0.0,
              enc_harmonics=(0.0, 0.0), isr_skip_prob=0.0)
    return kw


def motor_torque(kw: dict, current: float) -> float:
    """T_max at rest (N*m) for a drive current in percent, as the TMC5130's 0..31 scale gives it."""
    return kw["holding_torque"] * (math.ceil(0.31 * current) + 1) / 32.0


def simulated(joint: str, load_torque: float, seconds: float = SECONDS, **changes: float) -> np.ndarray:
    """The load angle (rad) from the simulator at every ISR period after the load torque steps
    from 0: sample i is at (i + 1) * T_ISR (the simulator integrates whole ISR periods, so the
    step takes effect at the ISR boundary before it). `changes`: SimStepper parameters that
    differ from the reference's (to see the comparison fail)."""
    kw = dict(link_parameters(joint), **changes)
    clock = VirtualClock()
    m = SimStepper(clock, seed=1, **kw)
    m.begin()
    m.set_current(CURRENT[joint])
    m.set_hold_current(CURRENT[joint])
    m.update()
    m.set_load_torque(load_torque)
    ys: list[float] = []
    last = m.load_angle()
    step_us = 1  # to the first ISR boundary, then well within an ISR period
    while len(ys) < int(seconds / T_ISR):
        clock.advance(step_us)
        m.update()
        y = m.load_angle()
        if y != last:
            ys.append(math.radians(y))
            last = y
            step_us = 100
    return np.array(ys)


def reference(joint: str, load_torque: float, t_eval: np.ndarray) -> np.ndarray:
    """The load angle (rad) of the same equations by solve_ivp (DOP853, rtol 1e-9)."""
    kw = link_parameters(joint)
    t_max = motor_torque(kw, CURRENT[joint])
    jr, jl = kw["inertia"], kw["load_inertia"]
    k, c = kw["coupling_stiffness"], kw["coupling_damping"]
    b, bl, corner = kw["damping"], kw["load_damping"] if "load_damping" in kw else 0.0, kw["corner_speed"]

    def rhs(_t: float, s: np.ndarray) -> list[float]:
        th_r, w_r, th_l, w_l = s
        t_em = t_max * math.sin(POLE_PAIRS * (0.0 - th_r)) / (1.0 + abs(w_r) / corner)
        spring = k * (th_r - th_l) + c * (w_r - w_l)
        return [w_r, (t_em - b * w_r - spring) / jr, w_l, (spring - bl * w_l - load_torque) / jl]
    sol = solve_ivp(rhs, (0.0, float(t_eval[-1])), [0.0, 0.0, 0.0, 0.0], method="DOP853", t_eval=t_eval,
                    rtol=1e-9, atol=1e-12)
    return sol.y[2]


def poles(y: np.ndarray, dt: float, order: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """The matrix pencil method: y[n] = sum_i a_i z_i^n for `order` poles z_i of uniformly sampled
    y (period dt). Returns (s_i = ln(z_i)/dt in 1/s, amplitudes a_i)."""
    n = len(y)
    cols = n // 3
    hankel = np.array([y[i:i + cols + 1] for i in range(n - cols)])
    _, _, vh = np.linalg.svd(hankel, full_matrices=False)
    v = vh[:order].conj().T
    z = np.linalg.eigvals(np.linalg.pinv(v[:-1]) @ v[1:])
    basis = np.vander(z, n, increasing=True).T
    amp = np.linalg.lstsq(basis, y.astype(complex), rcond=None)[0]
    return np.log(z.astype(complex)) / dt, amp


def fit(y: np.ndarray, dt: float, near: complex | None = None) -> dict:
    """Static deflection (rad: the pole at s = 0), and the undamped natural frequency (rad/s) and
    decay rate (1/s) of an oscillating mode: the one with the largest amplitude, or the one
    nearest the pole `near` (1/s)."""
    s, amp = poles(y, dt)
    still = int(np.argmin(abs(s)))
    osc = [i for i in range(len(s)) if i != still and s[i].imag > 0]
    if near is None:
        i = max(osc, key=lambda i: abs(amp[i]))
    else:
        i = min(osc, key=lambda i: abs(s[i] - near))
    return {"static": float(amp[still].real), "frequency": float(abs(s[i])), "decay": float(-s[i].real),
            "pole": complex(s[i])}


def compare(joint: str, **changes: float) -> dict:
    """Relative errors (%) of the simulator against the reference: frequency, decay, static.
    `changes`: parameters given to the simulator only."""
    kw = link_parameters(joint)
    load = LOAD_FRACTION * motor_torque(kw, CURRENT[joint])
    y_sim = simulated(joint, load, **changes)
    y_ref = reference(joint, load, T_ISR * np.arange(1, len(y_sim) + 1))
    ref = fit(y_ref, T_ISR)
    sim = fit(y_sim, T_ISR, near=ref["pole"])
    out = {name: 100.0 * abs(sim[name] - ref[name]) / abs(ref[name]) for name in ("frequency", "decay", "static")}
    out["reference"] = ref
    out["simulated"] = sim
    return out


def error_pct(joints=("J1", "J2", "J3", "J4")) -> float:
    """The largest relative error (%) of the three figures over the joints."""
    return max(max(r["frequency"], r["decay"], r["static"]) for r in map(compare, joints))


def main() -> int:
    worst = 0.0
    for joint in ("J1", "J2", "J3", "J4"):
        r = compare(joint)
        worst = max(worst, r["frequency"], r["decay"], r["static"])
        ref = r["reference"]
        print(f"# {joint}: reference {ref['frequency']:.1f} rad/s, decay {ref['decay']:.2f} 1/s, static "
              f"{math.degrees(ref['static']):.4f} deg; errors % frequency {r['frequency']:.3f} decay "
              f"{r['decay']:.3f} static {r['static']:.3f}", file=sys.stderr)
    print("safety.sim_reference_error_pct", "%.4g" % worst)
    return 0


if __name__ == "__main__":
    sys.exit(main())
