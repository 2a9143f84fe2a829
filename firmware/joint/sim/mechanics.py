"""The Bioscara arm's mechanics per joint, as SimStepper parameters (motor side, SI units).

Joint-side figures are converted through the reduction N (motor rad per joint rad, or per metre
for J2): an inertia or a torsional stiffness divides by N^2, a torque by N, a joint angle
multiplies by N. Where a figure comes from and how sure it is: README, "The simulated arm".

    kw = stepper_kwargs("J1")                       # the default arm: realistic, not kind
    kw = stepper_kwargs("J2", payload_kg=0.5, noise="harsh", encoder="as5600")
    SimStepper(clock, seed=1, **kw)
    stop_stiffness("J1", "soft")                    # N*m/rad and N*m*s/rad for add_obstacle()

MicroPython-compatible like the rest of joint.sim.
"""

import math

G = 9.81
DEG_PER_RAD = 180.0 / math.pi

# NEMA17 48 mm class stepper on the uStepper S32 (ustepper-model.md 8.3): holding torque at full
# scale, rotor inertia (68 g*cm^2 for 48 mm NEMA17 datasheets), rotor friction and viscous loss,
# torque roll-off to half at 120 rad/s (1150 rpm, the shape of 24 V NEMA17 pull-out curves; the
# model's 60 rad/s placeholder makes J3 lose steps at its shipped 14 rad/s^2, which the arm runs).
MOTOR = {"holding_torque": 0.45, "rotor_inertia": 6.8e-6, "coulomb": 0.005, "damping": 1e-4,
         "corner_speed": 120.0}

# Per joint, joint side: reduction; inertia of what the joint carries (arm stretched, no payload),
# kg*m^2 (J2: the moving mass, kg); payload lever arm, m (inertia += payload * lever^2); the
# transmission's stiffness (N*m/rad; J2: N/m axial) and damping ratio; backlash in motor degrees;
# friction at the joint (N*m; J2: screw thread friction coefficient); the end stop's contact
# stiffness (N*m/rad; J2: N/m) and damping ratio. Body regions (ISO_TS_15066) are met at the
# gripper (CONTACT_RADIUS: J1 0.614 m, J3 0.285 m from the axis; J4 at a 0.04 m jaw).
ARM = {
    "J1": {"reduction": 35.0, "inertia": 0.19, "lever": 0.614, "stiffness": 1500.0, "zeta": 0.1,
           "backlash_deg": 0.5, "friction": 0.05, "stop": 5000.0, "stop_zeta": 0.2},
    "J2": {"reduction": 2.0 * math.pi / 0.004, "mass": 1.5, "stiffness": 3.7e6, "zeta": 0.1,
           "backlash_deg": 4.5, "screw_mu": 0.1, "screw_d": 0.007, "extra_inertia": 1.3e-6,
           "stop": 1e6, "stop_zeta": 0.2},
    "J3": {"reduction": 24.0, "inertia": 0.030, "lever": 0.285, "stiffness": 600.0, "zeta": 0.1,
           "backlash_deg": 0.5, "friction": 0.03, "stop": 3000.0, "stop_zeta": 0.2},
    "J4": {"reduction": 12.0, "inertia": 3.0e-4, "lever": 0.02, "stiffness": 150.0, "zeta": 0.1,
           "backlash_deg": 1.0, "friction": 0.01, "stop": 1000.0, "stop_zeta": 0.2},
}

# Where an obstacle at the gripper is met, m from the axis (J2 moves linearly).
CONTACT_RADIUS = {"J1": 0.614, "J3": 0.285, "J4": 0.04}
# ISO/TS 15066:2016 Annex A, per body region: effective spring constant (N/mm, Table A.3) and
# quasi-static force limit (N, Table A.2), as transcribed in reference/safety-facts.md.
ISO_TS_15066 = {
    "hand": (75.0, 140.0),
    "lower_arm": (40.0, 160.0),
    "chest": (25.0, 140.0),
    "abdomen": (10.0, 110.0),
}
ISO_ABDOMEN_N = ISO_TS_15066["abdomen"][1]

# Encoder error figures. TLE5012B: overall angle error 1.0 deg at 25 C, 1.9 deg over -40..125 C
# (TLI5012B E1000 datasheet table 4-9; TLE5012B: "max. 1.0 deg ... with auto-calibration"),
# split into 1x and 2x per revolution terms; no noise figure in the datasheets consulted, so sigma
# brackets the former 0.7-count placeholder and the 3-4 counts at which the original homing lies.
# AS5600 (ams datasheet v1-06): 12 bits; 0.043 deg RMS with the 2x slow filter the Pico backend
# uses (0.015 deg at 16x); +-1 deg non-linearity assumed (same class as the TLE5012B).
ENCODERS = {
    "tle5012b": {"counts_per_rev": 32768, "sigma_deg": {"nominal": 1.5 * 360 / 32768, "harsh": 4.0 * 360 / 32768},
                 "harmonics": {"nominal": (0.6, 0.4), "harsh": (1.14, 0.76)}},
    "as5600": {"counts_per_rev": 4096, "sigma_deg": {"nominal": 0.043, "harsh": 0.086},
               "harmonics": {"nominal": (0.6, 0.4), "harsh": (1.14, 0.76)}},
}

# Skipped library ISR ticks (SPI semaphore held by the main thread), ustepper-model.md 8.3.
ISR_SKIP = {"nominal": 0.005, "harsh": 0.02}


def _reflect(joint, payload_kg):
    """(load inertia, coupling stiffness, coupling damping, load friction, load torque, stop k, stop c,
    soft k) on the motor side."""
    a = ARM[joint]
    n = a["reduction"]
    n2 = n * n
    if joint == "J2":
        mass = a["mass"] + payload_kg
        jl = mass / n2
        weight = mass * G
        # Thread friction of a 30-degree trapezoidal screw: mu * F * d/2 / cos(15 deg), at the motor.
        friction = a["screw_mu"] * weight * 0.5 * a["screw_d"] / math.cos(math.radians(15.0))
        # Gravity pulls down; with the negative reduction down is +motor angle (see default.toml).
        torque = -weight / n
    else:
        jl = (a["inertia"] + payload_kg * a["lever"] ** 2) / n2
        friction = a["friction"] / n
        torque = 0.0
    k = a["stiffness"] / n2
    c = 2.0 * a["zeta"] * math.sqrt(k * jl)
    ks = a["stop"] / n2
    cs = 2.0 * a["stop_zeta"] * math.sqrt(ks * jl)
    return jl, k, c, friction, torque, ks, cs, region_stiffness(joint, "abdomen")


def region_stiffness(joint, region):
    """A body region's ISO/TS 15066 spring (N/mm) met at the gripper (J2: at the nut), as a
    motor-side torsional stiffness, N*m/rad: k * r^2 / N^2 (J2: k / N^2, N in rad/m)."""
    k = ISO_TS_15066[region][0] * 1000.0
    n = ARM[joint]["reduction"]
    lever = 1.0 if joint == "J2" else CONTACT_RADIUS[joint]
    return k * lever * lever / (n * n)


def stepper_kwargs(joint, payload_kg=0.0, noise="nominal", encoder="tle5012b"):
    """SimStepper keyword arguments for J1..J4 of the arm (motor side)."""
    jl, k, c, friction, torque, ks, cs, _ = _reflect(joint, payload_kg)
    enc = ENCODERS[encoder]
    cpr = enc["counts_per_rev"]
    return {
        "holding_torque": MOTOR["holding_torque"],
        "inertia": MOTOR["rotor_inertia"] + ARM[joint].get("extra_inertia", 0.0),
        "coulomb": MOTOR["coulomb"],
        "damping": MOTOR["damping"],
        "corner_speed": MOTOR["corner_speed"],
        "load_inertia": jl,
        "coupling_stiffness": k,
        "coupling_damping": c,
        "backlash": ARM[joint]["backlash_deg"],
        "load_friction": friction,
        "load_torque": torque,
        "wall_stiffness": ks,
        "wall_damping": cs,
        "counts_per_rev": cpr,
        "enc_sigma": enc["sigma_deg"][noise] * cpr / 360.0,
        "enc_harmonics": enc["harmonics"][noise],
        "isr_skip_prob": ISR_SKIP[noise],
        "encoder_board": int(joint[1]),
    }


def stop_stiffness(joint, kind="rigid", payload_kg=0.0):
    """(stiffness N*m/rad, damping N*m*s/rad) on the motor side of an obstacle: "rigid" (the end
    stop block's contact), a body region of ISO_TS_15066, or "soft" (its softest, the abdomen);
    damping ratio 0.2."""
    jl, _, _, _, _, ks, cs, _ = _reflect(joint, payload_kg)
    if kind == "rigid":
        return ks, cs
    k = region_stiffness(joint, "abdomen" if kind == "soft" else kind)
    return k, 2.0 * ARM[joint]["stop_zeta"] * math.sqrt(k * jl)


def contact_force_n(joint, torque):
    """The force (N) at the contact (CONTACT_RADIUS; J2: at the screw's nut) of a motor-side
    torque (N*m) pressing an obstacle."""
    n = abs(ARM[joint]["reduction"])
    return abs(torque) * n if joint == "J2" else abs(torque) * n / CONTACT_RADIUS[joint]


def homing_error_bound_deg(joint, homing_current, noise="nominal", payload_kg=0.0):
    """Motor degrees by which the encoder zero set at the end of a homing can miss the link's
    stop: the transmission and the stop deflect under the homing push (the motor's torque at
    `homing_current` percent), plus backlash and the encoder's systematic error. Sensorless homing
    on a compliant joint cannot do better; the firmware can only avoid adding to it."""
    _, k, _, _, _, ks, _, _ = _reflect(joint, payload_kg)
    push = MOTOR["holding_torque"] * (math.ceil(0.31 * homing_current) + 1) / 32.0
    return (ARM[joint]["backlash_deg"] + sum(ENCODERS["tle5012b"]["harmonics"][noise])
            + (push / k + push / ks) * DEG_PER_RAD)


def position_error_bound_deg(joint, homing_current, noise="nominal", payload_kg=0.0):
    """Motor degrees between the measured and the true link position of a homed joint at rest:
    the homing error, then backlash, encoder error and the static load (gravity) on the spring."""
    _, k, _, _, torque, _, _, _ = _reflect(joint, payload_kg)
    return (homing_error_bound_deg(joint, homing_current, noise, payload_kg) + ARM[joint]["backlash_deg"]
            + sum(ENCODERS["tle5012b"]["harmonics"][noise]) + abs(torque) / k * DEG_PER_RAD)
