"""What a torque-based stall detector can see of a collision, from the simulated arm's mechanics
(firmware/joint/sim/mechanics.py): a quasi-static estimate per joint, speed and obstacle.

A stepper follows its field within the load angle, asin(T / T_max) electrical radians (1024 usteps
per electrical period), until the load torque T exceeds its pull-out torque T_max; then it slips
poles and the field/encoder tracking detector sees the rotor stop. Against an obstacle of stiffness
k_obs in series with the transmission's k_t, the torque grows by k_eff * w per second at motor speed
w. So, from the first contact:

* overpowered after (T_max - T_free) / (k_eff * w): the earliest a lost-step detector can fire;
* in 250 ms (issue 11's worst latency) the load angle grows by the usteps printed, which only a
  detector of the load angle could see -- against the encoder's harmonic error (datasheet: up to
  0.046 usteps per ustep turned, 12/256) and noise (TLE5012B harsh: 4 counts = 6 usteps sigma);
* the force on the obstacle at the gripper (J2: at the screw's nut) then and at pull-out, against
  ISO/TS 15066's quasi-static limit for the abdomen (110 N; the soft obstacle is its 10 N/mm): when
  a soft contact reaches it and by how much the load angle has grown then (inf: the motor slips
  before the force gets there).

T_free is what unobstructed motion already loads the motor with at cruise (gravity on J2, friction,
payload), T_max the torque at the shipped current with the model's roll-off. Backlash (J2: 4.5
motor degrees) comes on top where the load is preloaded the other way.

    python bench/contact_bounds.py
"""

import math
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path[:0] = [os.path.join(HERE, "..", "firmware")]

from joint.sim import mechanics as M  # noqa: E402

CURRENT = {"J1": 20, "J2": 8, "J3": 20, "J4": 20}  # shipped drive current, % (default.toml)
ISO_ABDOMEN_N = M.ISO_ABDOMEN_N
USTEPS_PER_RAD_E = 1024 / (2 * math.pi)  # load angle: usteps per electrical radian
LATENCY_S = 0.25


def t_max(joint, w):
    """Pull-out torque (N*m) at the shipped current and motor speed w (rad/s), as the simulator."""
    scale = (math.ceil(0.31 * CURRENT[joint]) + 1) / 32.0
    return M.MOTOR["holding_torque"] * scale / (1.0 + w / M.MOTOR["corner_speed"])


force_n = M.contact_force_n


def load_angle_usteps(t, tmax):
    return USTEPS_PER_RAD_E * math.asin(min(1.0, t / tmax))


def bounds(joint, rpm, kind, payload_kg=0.0):
    jl, k_t, _, friction, gravity, _, _, _ = M._reflect(joint, payload_kg)
    k_obs, _ = M.stop_stiffness(joint, kind, payload_kg)
    k_eff = 1.0 / (1.0 / k_t + 1.0 / k_obs)
    w = rpm * 2 * math.pi / 60.0
    tmax = t_max(joint, w)
    t_free = abs(gravity) + friction + M.MOTOR["coulomb"] + M.MOTOR["damping"] * w
    rate = k_eff * w  # N*m/s of obstacle torque
    overpowered_s = (tmax - t_free) / rate
    d_t = min(rate * LATENCY_S, tmax - t_free)
    grow = load_angle_usteps(t_free + d_t, tmax) - load_angle_usteps(t_free, tmax)
    f_max = force_n(joint, tmax - t_free)
    if f_max <= ISO_ABDOMEN_N:  # the motor slips first: the limit is never reached
        iso_s = iso_grow = math.inf
    else:
        iso_s = ISO_ABDOMEN_N / force_n(joint, rate)
        iso_grow = load_angle_usteps(t_free + rate * iso_s, tmax) - load_angle_usteps(t_free, tmax)
    return overpowered_s, grow, force_n(joint, d_t), f_max, iso_s, iso_grow


def main():
    print("joint rpm obstacle: overpowered after (ms) | load angle +usteps in 250 ms | force at 250 ms / "
          "at pull-out (N) | 110 N reached after (ms), load angle then +usteps")
    for joint in ("J1", "J2", "J3", "J4"):
        for rpm in (10.0, 30.0, 120.0):
            for kind in ("rigid", "soft"):
                over, grow, f250, fmax, iso, iso_grow = bounds(joint, rpm, kind)
                print("%s %5g %-5s: %8.0f | %6.1f | %8.1f / %7.1f | %8.0f %6.1f"
                      % (joint, rpm, kind, over * 1e3, grow, f250, fmax, iso * 1e3, iso_grow))


if __name__ == "__main__":
    main()
