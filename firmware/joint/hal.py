"""Motor hardware abstraction: what the joint core needs from a stepper with an encoder.

Units are those of the uStepper S32 library the original firmware drove, so the stall and homing
constants keep their meaning on every backend:

* full steps: 200 per revolution; microsteps ("usteps"): 1/256 full step, 51200 per revolution;
* angles in motor degrees, speeds in motor RPM (encoder-measured unless stated otherwise);
* PID error in usteps: driver position minus encoder position, bounded by the closed-loop
  re-synchronisation (see ustepper-model.md section 3.3);
* currents in percent of the driver's full scale.

Every call returns promptly: motion commands start a ramp, `stop` starts a deceleration. Blocking
sequences (homing, orientation check) are built by the core from these primitives.
`update()` is called once per main-loop iteration before any getter.
"""

FULL_STEPS_PER_REV = 200
MICROSTEPS = 256
USTEPS_PER_REV = FULL_STEPS_PER_REV * MICROSTEPS
USTEPS_PER_DEG = USTEPS_PER_REV / 360.0


class MotorHAL:
    """Interface of a joint motor backend. Subclasses implement every method."""

    def begin(self):
        """Power-on setup: closed-loop mode with 200 full steps, closed loop still inactive."""
        raise NotImplementedError

    def update(self):
        """Service the backend (advance the simulation, feed the step generator, read sensors)."""
        raise NotImplementedError

    def enable_closed_loop(self):
        raise NotImplementedError

    def disable_closed_loop(self):
        """Closed loop off; the PID error freezes at its last value."""
        raise NotImplementedError

    def set_control_threshold(self, usteps):
        """Re-synchronise the driver to the encoder when |error| >= usteps."""
        raise NotImplementedError

    def set_max_velocity(self, full_steps_per_s):
        raise NotImplementedError

    def set_max_acceleration(self, full_steps_per_s2):
        raise NotImplementedError

    def set_max_deceleration(self, full_steps_per_s2):
        raise NotImplementedError

    def set_rpm(self, rpm):
        """Velocity mode at `rpm` (sign is direction), ramping with the max acceleration."""
        raise NotImplementedError

    def move_steps(self, usteps):
        """Positioning mode, relative to the driver's current position."""
        raise NotImplementedError

    def move_angle(self, degrees):
        """Positioning mode, relative move of `degrees`."""
        raise NotImplementedError

    def move_to_angle(self, degrees):
        """Positioning mode to an absolute encoder angle (degrees since home)."""
        raise NotImplementedError

    def stop(self, hard=True):
        """Decelerate to standstill (hard: at the driver's maximum rate) and hold position."""
        raise NotImplementedError

    def set_current(self, percent):
        raise NotImplementedError

    def set_hold_current(self, percent):
        raise NotImplementedError

    def set_brake_mode(self, mode):
        """0 freewheel, 1 coolbrake (coils shorted), 2 hardbrake (holding current)."""
        raise NotImplementedError

    def set_home(self):
        """Zero the encoder angle and the driver position at the current position."""
        raise NotImplementedError

    def set_inverted(self, inverted):
        """Reverse the driver direction (the shaft bit set by the orientation check)."""
        raise NotImplementedError

    def angle_moved(self):
        """Encoder angle since home, degrees."""
        raise NotImplementedError

    def encoder_rpm(self):
        raise NotImplementedError

    def driver_rpm(self):
        """Speed of the ramp generator, RPM."""
        raise NotImplementedError

    def pid_error(self):
        raise NotImplementedError

    def position_reached(self):
        """True when a positioning move has arrived (False in velocity mode while moving)."""
        raise NotImplementedError

    def field_position(self):
        """Usteps the driver has advanced the coil field since begin(), an int wrapping at 2**30:
        the driver position without the closed loop's relabels (set_home does not reset it).
        Stall and homing evidence compare it with the encoder."""
        raise NotImplementedError
