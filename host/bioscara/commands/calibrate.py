"""`bioscara calibrate JOINT`: measure the joint's encoder error over a motor turn, store the
correction table in the joint's configuration file, and measure again through it.

The simulated joints' files are reached over the bus; a real joint's over its board's USB serial
port (`--port`, as `bioscara flash` reaches it), which stops the board's firmware while the file is
written: the table is therefore written after the measurement, and the board reset."""

from __future__ import annotations

import argparse

from .. import encoder_calibration as calibration
from .. import firmware_flash, motion, mpboard, report
from ..arm import Arm
from ..communicator import Communicator
from ..errors import InvalidArgumentError, NotHomedError
from ..mpboard import FlashError
from ..session import Session
from .options import one_joint

NAME = "calibrate"
HELP = ("installation: turn a homed, unloaded joint's motor slowly one turn each way, fit its encoder's error "
        "and store the correction in the joint (it reboots, homes again and is measured through it); on a real "
        "arm the table is written over the joint's USB serial port (--port)")
EXAMPLES = (
    ('bioscara calibrate j1', "j1's encoder: its error before and after the correction, in motor degrees"),
    ('bioscara calibrate j3 --json', 'the same as JSON, with the table written to the joint'),
    ('bioscara calibrate j2 --bus smbus:1 --port /dev/ttyACM1',
     "a real arm: the table goes into j2's configuration file over its board's USB serial port"),
)
BOOT_TIMEOUT_S = 10.0  # how long the joint may take to answer on the bus after its board's reset


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("joint", type=one_joint, help="j1..j4")
    parser.add_argument("--port", metavar="PORT",
                        help="on a real arm: the joint's USB serial port, e.g. /dev/ttyACM0 (`bioscara ports` lists "
                        "them), over which the table is written into its configuration file; without it a real "
                        "arm's table is measured and printed, not stored (the simulated joints need none)")
    parser.add_argument("--board", choices=[b for b in firmware_flash.boards() if not b.endswith("_circuitpython")],
                        default=firmware_flash.DEFAULT_BOARD,
                        help="the joint's board, as `bioscara flash --board` names it (default: %(default)s); "
                        "an S32's configuration is written with dfu-util, which --port does not do yet")


def run(args: argparse.Namespace, session: Session) -> int:
    name = args.joint
    jc = session.config.joints[name]
    bus = session.bus
    # Everything that can refuse is checked before the motor turns.
    if bus.reaches_config_files:
        if args.port:
            raise InvalidArgumentError(f"{bus.describe()} reaches the simulated joints' configuration files itself: "
                                       "give no --port")
        config_file = bus.joint_config_file(jc.address)
    elif args.port:
        if args.board == "s32":
            raise InvalidArgumentError("--port writes a MicroPython board's configuration file; an S32 keeps its "
                                       "configuration in flash, which calibrate cannot write yet: calibrate without "
                                       "--port and add the table as encoder.correction to the configuration "
                                       "`bioscara flash --board s32 --joint-config FILE` writes")
        if bus.describe() == f"serial:{args.port}":
            raise InvalidArgumentError(f"{args.port} is the HIL bridge the bus runs over; --port is the joint's own "
                                       "USB serial port (`bioscara ports` tells them apart)")
        mpboard.check_port(args.port)
    arm = _ready_arm(session, name)
    before, zero = _measure(arm, name)
    measured = before.table_millideg()
    arm.release()
    if bus.reaches_config_files:
        source = f"{name}'s configuration file"
        updated = _corrected(config_file, measured, source)
        bus.write_joint_config_file(jc.address, updated)
        bus.reboot_joint(jc.address)
    elif args.port:
        source = f"{args.port}: {firmware_flash.CONFIG_PATH}"
        board = mpboard.open_board(args.port)
        try:
            updated = firmware_flash.update_config(board, name.upper(), jc.address,
                                                   lambda on_board: _corrected(on_board, measured, source))
        finally:
            board.close()
        identity = firmware_flash.check_identity(bus, name.upper(), jc.address, timeout=BOOT_TIMEOUT_S)
        if not identity.ok:
            raise FlashError("after writing the table: " + "; ".join(identity.problems))
    else:
        return _measured_only(session, name, before, zero, measured, args.board)
    table = calibration.correction_in(updated, source)
    # The reboot loses the zero: home again, then turn once more through the correction.
    arm = _ready_arm(session, name, home=True)
    after, _ = _measure(arm, name)
    result = {**report.joint_ref(name, jc), "encoder_zero_deg": zero, "table_millideg": table,
              "error_before_deg": before.peak_deg, "error_after_deg": after.peak_deg,
              "noise_rms_deg": after.residual_rms_deg, "stored": True}
    session.emit(result, "\n".join((
        f"{name}: encoder error over a motor turn {before.peak_deg:.3f} deg before, {after.peak_deg:.3f} deg after "
        f"calibration ({100.0 * (1.0 - after.peak_deg / before.peak_deg):.0f} % less)",
        f"{name}: {len(table)}-point correction stored in {source} (encoder.correction); "
        f"reading noise {after.residual_rms_deg:.3f} deg rms")))
    return 0


def _corrected(config_file: bytes, measured: list[int], source: str) -> bytes:
    """The configuration file with its correction table (if any) refined by the error `measured`
    through it."""
    table = calibration.combined(calibration.correction_in(config_file, source), measured)
    return calibration.with_correction(config_file, table, source)


def _measured_only(session: Session, name: str, before: calibration.Fit, zero: float, measured: list[int],
                   board: str) -> int:
    """A real arm without --port: the measurement, and how to store it on `board`."""
    jc = session.config.joints[name]
    if board == "s32":
        how = ("add it as encoder.correction to the configuration `bioscara flash --board s32 --joint-config FILE` "
               "writes")
    else:
        how = (f"store it with `bioscara calibrate {name} --port PORT`, PORT the joint's USB serial port "
               "(`bioscara ports` lists them)")
    session.emit({**report.joint_ref(name, jc), "encoder_zero_deg": zero, "table_millideg": measured,
                  "error_before_deg": before.peak_deg, "noise_rms_deg": before.residual_rms_deg, "stored": False},
                 "\n".join((
                     f"{name}: encoder error over a motor turn {before.peak_deg:.3f} deg (through the correction it "
                     f"uses, if any); reading noise {before.residual_rms_deg:.3f} deg rms",
                     f"{name}: measured table (motor millidegrees): {measured}",
                     f"not stored: {session.bus.describe()} reaches the I2C only; {how}")))
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
