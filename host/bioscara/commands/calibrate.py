"""`bioscara calibrate JOINT`: measure the joint's encoder error over a motor turn, store the
correction table in the joint's configuration file, and measure again through it."""

from __future__ import annotations

import argparse

from .. import encoder_calibration as calibration
from .. import motion, report
from ..arm import Arm
from ..communicator import Communicator
from ..errors import InvalidArgumentError, NotHomedError
from ..session import Session
from .options import one_joint

NAME = "calibrate"
HELP = ("installation: turn a homed, unloaded joint's motor slowly one turn each way, fit its encoder's error "
        "and store the correction in the joint (it reboots, homes again and is measured through it)")
EXAMPLES = (
    ('bioscara calibrate j1', "j1's encoder: its error before and after the correction, in motor degrees"),
    ('bioscara calibrate j3 --json', 'the same as JSON, with the table written to the joint'),
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("joint", type=one_joint, help="j1..j4")


def run(args: argparse.Namespace, session: Session) -> int:
    name = args.joint
    jc = session.config.joints[name]
    bus = session.bus
    source = f"{name}'s configuration file"
    config_file = bus.joint_config_file(jc.address)  # first: a bus that cannot store the table turns nothing
    arm = _ready_arm(session, name)
    before, zero = _measure(arm, name)
    table = calibration.combined(calibration.correction_in(config_file, source), before.table_millideg())
    updated = calibration.with_correction(config_file, table, source)
    arm.release()
    bus.write_joint_config_file(jc.address, updated)
    bus.reboot_joint(jc.address)
    # The reboot loses the zero: home again, then turn once more through the correction.
    arm = _ready_arm(session, name, home=True)
    after, _ = _measure(arm, name)
    result = {**report.joint_ref(name, jc), "encoder_zero_deg": zero, "table_millideg": table,
              "error_before_deg": before.peak_deg, "error_after_deg": after.peak_deg,
              "noise_rms_deg": after.residual_rms_deg}
    session.emit(result, "\n".join((
        f"{name}: encoder error over a motor turn {before.peak_deg:.3f} deg before, {after.peak_deg:.3f} deg after "
        f"calibration ({100.0 * (1.0 - after.peak_deg / before.peak_deg):.0f} % less)",
        f"{name}: {len(table)}-point correction stored in the joint's configuration (encoder.correction); "
        f"reading noise {after.residual_rms_deg:.3f} deg rms")))
    return 0


def _ready_arm(session: Session, name: str, *, home: bool = False) -> Arm:
    """The joint's arm, configured and enabled (homed first with `home`); NotHomedError if it is not."""
    arm = session.arm_of([name])
    arm.configure()
    if home:
        arm.activate()
        motion.home(arm, Communicator(arm, frequency=50.0), [name])
    if not arm[name].joint.is_homed():
        raise NotHomedError(f"not homed: run `bioscara home {name}` first (calibration turns it within its limits)",
                            joint=name)
    if not home:
        arm.activate()
    return arm


def _measure(arm: Arm, name: str) -> tuple[calibration.Fit, float]:
    """One turn each way (first toward the side with room), fitted; and ENCODERZERO."""
    aj = arm[name]
    joint, jc = aj.joint, aj.config
    position = joint.get_position()
    room = calibration.room_needed(joint)
    if position + room <= jc.max:
        first = 1
    elif position - room >= jc.min:
        first = -1
    else:
        raise InvalidArgumentError(f"calibration turns the motor {calibration.TURNS:g} turns each way: "
                                   f"{report.value(room, jc)} of room on one side of "
                                   f"{report.value(position, jc)}, which the limits do not leave", joint=name)
    motor_first = first if joint.transmission.reduction > 0 else -first
    with joint.visit_legacy():  # ENCODERZERO is not in the v2 state block
        (zero,) = joint.read_register("ENCODERZERO")
    sweeps = [calibration.sweep(joint, arm.bus, motor_first), calibration.sweep(joint, arm.bus, -motor_first)]
    return calibration.fit(sweeps, float(zero)), float(zero)
