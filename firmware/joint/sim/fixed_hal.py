"""The HAL's fixed-point units (hal.py) in front of a motor model that speaks plain floats.

The simulated stepper keeps the uStepper library's units (degrees, rpm, full steps/s, float
usteps), which its own tests and the simulator's mechanics use; the firmware core speaks the
board's integers. This wrapper converts at the boundary, both ways, and passes everything else
(simulator hooks such as `set_end_stops`, `block`) straight through.
"""

from ..motion.fixed import ANGLE_Q, RPM_Q, STEPS_Q, to_q
from ..motion.hal import MotorHAL

_ANGLE = float(1 << ANGLE_Q)
_RPM = float(1 << RPM_Q)
_STEPS = float(1 << STEPS_Q)


class FixedPointHAL(MotorHAL):
    def __init__(self, motor):
        self.motor = motor

    def __getattr__(self, name):
        return getattr(self.motor, name)

    def begin(self):
        self.motor.begin()

    def update(self):
        self.motor.update()

    def enable_closed_loop(self):
        self.motor.enable_closed_loop()

    def disable_closed_loop(self):
        self.motor.disable_closed_loop()

    def set_control_threshold(self, usteps):
        self.motor.set_control_threshold(usteps)

    def set_max_velocity(self, full_steps_per_s):
        self.motor.set_max_velocity(full_steps_per_s / _STEPS)

    def set_max_acceleration(self, full_steps_per_s2):
        self.motor.set_max_acceleration(full_steps_per_s2 / _STEPS)

    def set_max_deceleration(self, full_steps_per_s2):
        self.motor.set_max_deceleration(full_steps_per_s2 / _STEPS)

    def set_rpm(self, rpm):
        self.motor.set_rpm(rpm / _RPM)

    def move_steps(self, usteps):
        self.motor.move_steps(usteps)

    def move_angle(self, degrees):
        self.motor.move_angle(degrees / _ANGLE)

    def move_to_angle(self, degrees):
        self.motor.move_to_angle(degrees / _ANGLE)

    def stop(self, hard=True):
        self.motor.stop(hard)

    def set_current(self, percent):
        self.motor.set_current(percent)

    def set_hold_current(self, percent):
        self.motor.set_hold_current(percent)

    def set_brake_mode(self, mode):
        self.motor.set_brake_mode(mode)

    def set_home(self):
        self.motor.set_home()

    def set_inverted(self, inverted):
        self.motor.set_inverted(inverted)

    def angle_moved(self):
        return to_q(self.motor.angle_moved(), ANGLE_Q)

    def encoder_rpm(self):
        return to_q(self.motor.encoder_rpm(), RPM_Q)

    def driver_rpm(self):
        return to_q(self.motor.driver_rpm(), RPM_Q)

    def pid_error(self):
        return to_q(self.motor.pid_error(), 0)

    def position_reached(self):
        return self.motor.position_reached()

    def magnet(self):
        return self.motor.magnet()

    def field_position(self):
        return self.motor.field_position()

    def set_encoder_correction(self, table):
        self.motor.set_encoder_correction(table)

    def encoder_zero(self):
        return to_q(self.motor.encoder_zero(), ANGLE_Q)
