"""Helpers shared by the firmware tests (CPython and the MicroPython unix port alike)."""

from joint.config import schema as config
from joint.spec import protocol
from joint.core.controller import JointController
from joint.motion.fixed import ANGLE_Q, RPM_Q, to_q
from joint.motion.hal import MAGNET_OK, MotorHAL
from joint.links.i2c_target import I2CTargetAdapter
from joint.console.log import Logger
from joint.sim.clock import VirtualClock
from joint.sim.i2c_target import FakeI2CTarget


class RecordingMotor(MotorHAL):
    """A motor double that records every command; getters return settable values.

    The HAL speaks fixed point (hal.py); this double records and takes plain units (degrees,
    rpm, full steps/s, usteps) so the tests read like the protocol."""

    def __init__(self):
        self.calls = []
        self.angle = 0.0
        self.rpm = 0.0
        self.ramp_rpm = 0.0
        self.error = 0.0
        self.reached = True
        self.field = 0  # field_position(), usteps
        self.magnet_health = MAGNET_OK  # magnet(): what the encoder's status says
        self.wiring = 0  # +1/-1: relative moves change `angle` like a (mis)wired motor; 0: it never moves

    def _record(self, name, *args):
        self.calls.append((name,) + args)

    def names(self):
        return [c[0] for c in self.calls]

    def begin(self):
        self._record("begin")

    def update(self):
        pass

    def enable_closed_loop(self):
        self._record("enable_closed_loop")

    def disable_closed_loop(self):
        self._record("disable_closed_loop")

    def set_control_threshold(self, usteps):
        self._record("set_control_threshold", usteps)

    def set_max_velocity(self, full_steps_per_s):
        self._record("set_max_velocity", full_steps_per_s / 16)

    def set_max_acceleration(self, full_steps_per_s2):
        self._record("set_max_acceleration", full_steps_per_s2 / 16)

    def set_max_deceleration(self, full_steps_per_s2):
        self._record("set_max_deceleration", full_steps_per_s2 / 16)

    def set_rpm(self, rpm):
        self._record("set_rpm", rpm / 65536)

    def move_steps(self, usteps):
        self._record("move_steps", usteps)

    def move_angle(self, degrees):
        degrees = degrees / 4096
        self._record("move_angle", degrees)
        self.angle += self.wiring * degrees

    def move_to_angle(self, degrees):
        self._record("move_to_angle", degrees / 4096)

    def stop(self, hard=True):
        self._record("stop", hard)

    def set_current(self, percent):
        self._record("set_current", percent)

    def set_hold_current(self, percent):
        self._record("set_hold_current", percent)

    def set_brake_mode(self, mode):
        self._record("set_brake_mode", mode)

    def set_home(self):
        self._record("set_home")

    def set_inverted(self, inverted):
        self._record("set_inverted", inverted)

    def angle_moved(self):
        return to_q(self.angle, ANGLE_Q)

    def encoder_rpm(self):
        return to_q(self.rpm, RPM_Q)

    def driver_rpm(self):
        return to_q(self.ramp_rpm, RPM_Q)

    def pid_error(self):
        return to_q(self.error, 0)

    def position_reached(self):
        return self.reached

    def field_position(self):
        return self.field

    def magnet(self):
        self._record("magnet")
        return self.magnet_health

    def encoder_zero(self):
        return 0


class Rig:
    """One joint controller behind a fake I2C target, with a recording motor, in virtual time."""

    def __init__(self, port="rp2", whole_reply_writes=True, cfg=None, boot=True):
        self.clock = VirtualClock()
        self.motor = RecordingMotor()
        self.lines = []
        self.cfg = cfg or config.default("J1")
        self.core = JointController(self.motor, self.clock, self.cfg,
                                    Logger("J1", write=self.lines.append))
        self.target = FakeI2CTarget(self.cfg.address or 0x11, port)
        self.adapter = I2CTargetAdapter(self.core, whole_reply_writes)
        self.adapter.attach(self.target)
        if boot:
            self.run_ms(2000)
            assert self.core.ready
            self.motor.calls = []

    def run_ms(self, ms):
        for _ in range(ms):
            self.clock.advance(1000)
            self.core.service()

    def xfer(self, data, read_len):
        return self.target.transfer(data, read_len)

    def command(self, name, *values):
        """Write register `name` with `values` and read the 1-byte flags reply, as the original host does."""
        reg = protocol.register(name)
        return self.xfer(bytes([reg.addr]) + reg.encode(*values), 1)[0]

    def read(self, name):
        """Register read as the original host does it: [reg], repeated START, payload + flags."""
        reg = protocol.register(name)
        reply = self.xfer(bytes([reg.addr]), reg.rsize + 1)
        return reg.decode(reply[:-1]), reply[-1]

    def assert_handler_alive(self):
        assert self.target.handler_installed, "IRQ handler removed after: %r" % (self.target.last_failure,)
        assert self.target.handler_failures == 0


class Xorshift:
    """A tiny deterministic PRNG with identical output on both interpreters."""

    def __init__(self, seed=0x2545F491):
        self.state = seed & 0xFFFFFFFF or 1

    def next(self):
        x = self.state
        x ^= (x << 13) & 0xFFFFFFFF
        x ^= x >> 17
        x ^= (x << 5) & 0xFFFFFFFF
        self.state = x
        return x

    def below(self, n):
        return self.next() % n

    def bytes(self, n):
        return bytes(self.below(256) for _ in range(n))


class SimRig:
    """One joint running the real firmware on the simulated stepper, on a simulated bus."""

    def __init__(self, joint="J1", low_deg=None, high_deg=None, seed=1, mechanics=None, chip=None, **stepper_kwargs):
        """`mechanics`: None for the bare motor model (ustepper-model.md 8.3 defaults), or a dict of
        joint.sim.mechanics.stepper_kwargs() options ({} = the arm's nominal joint); explicit
        stepper_kwargs override either. `chip`: the bus's cost table (None: the repository's)."""
        from joint.sim import mechanics as arm
        from joint.sim.bus import SimJointBus
        from joint.sim.joint import make_joint
        from joint.sim.stepper import SimStepper
        self.clock = VirtualClock()
        if mechanics is not None:
            kw = arm.stepper_kwargs(joint, **mechanics)
            kw.update(stepper_kwargs)
            stepper_kwargs = kw
        self.stepper = SimStepper(self.clock, seed=seed, **stepper_kwargs)
        self.stepper.set_end_stops(low_deg, high_deg)
        self.lines = []
        self.joint = make_joint(joint, self.clock, self.stepper, write=self.lines.append)
        self.bus = SimJointBus(self.clock, (self.joint,), chip=chip)
        self.addr = self.joint.cfg.address
        assert self.bus.boot(), "joint did not finish booting"

    @property
    def flags(self):
        return self.joint.core.flags

    def command(self, name, *values):
        reg = protocol.register(name)
        return self.bus.transfer(self.addr, bytes([reg.addr]) + reg.encode(*values), 1)[0]

    def read(self, name):
        reg = protocol.register(name)
        reply = self.bus.transfer(self.addr, bytes([reg.addr]), reg.rsize + 1)
        return reg.decode(reply[:-1]), reply[-1]

    def ping(self):
        return self.read("PING")[1]

    def poll(self, seconds, period=0.02, until=None):
        """Poll the flags like a host control loop; stop early when until(flags) is true."""
        t_end = self.clock.now_us + int(seconds * 1e6)
        while self.clock.now_us < t_end:
            self.bus.sleep(period)
            flags = self.ping()
            if until is not None and until(flags):
                return True
        return False

    def enable(self, current=20, sensitivity=None, accel_deg=None, vel_deg=None):
        assert self.command("SETUP", current, current, 0, 0) & protocol.FLAG_NOTENABLED == 0
        if sensitivity is not None:
            self.command("ENABLESTALLGUARD", sensitivity)
        if accel_deg is not None:
            self.command("SETMAXACCELERATION", accel_deg)
        if vel_deg is not None:
            self.command("SETMAXVELOCITY", vel_deg)
