"""Motor hardware abstraction: what the joint core needs from a stepper with an encoder.

Quantities are those of the uStepper S32 library the original firmware drove, so the stall and
homing constants keep their meaning on every backend, but every value crossing this interface is
an integer in fixed point (`fixed.py`), because the core calls it at 1 kHz and a float is a heap
object on the board:

* microsteps ("usteps", int): 1/256 full step, 51200 per revolution; full steps: 200 per rev;
* angles: motor degrees in Q12 (x 4096, fixed.ANGLE_Q);
* speeds: motor rpm in Q16 (x 65536, fixed.RPM_Q), encoder-measured unless stated otherwise;
* max velocity / acceleration: full steps/s and full steps/s^2 in Q4 (x 16, fixed.STEPS_Q);
* PID error: int usteps, driver position minus encoder position, bounded by the closed-loop
  re-synchronisation (see ustepper-model.md section 3.3);
* currents in percent of the driver's full scale.

Every call returns promptly: motion commands start a ramp, `stop` starts a deceleration. Blocking
sequences (homing, orientation check) are built by the core from these primitives.
`update()` is called once per main-loop iteration before any getter; it and the getters must not
allocate on the board. A backend that models in floats converts at its boundary
(sim/fixed_hal.py).
"""

FULL_STEPS_PER_REV = 200
MICROSTEPS = 256
USTEPS_PER_REV = FULL_STEPS_PER_REV * MICROSTEPS

# The encoder magnet's health, as the sensor reports it (`MotorHAL.magnet`); the order is that of
# homing.py's outcomes NO_MAGNET, WEAK_MAGNET, STRONG_MAGNET.
MAGNET_OK = 0
MAGNET_MISSING = 1  # no magnet detected, or the sensor did not answer
MAGNET_WEAK = 2  # too far from the sensor: the angle is noisy
MAGNET_STRONG = 3  # too close: the sensor saturates


class MotorHAL:
    """Interface of a joint motor backend. Subclasses implement every method but the closed loop's
    switch and threshold, whose setters here store `_closed_loop` and `_threshold` (usteps) for the
    subclass's update() to read; the subclass sets both at construction (off, 10), and the encoder
    correction (`set_encoder_correction`, `_corrected`), which needs `_encoder_cpr`, the encoder's
    counts per turn (a power of two)."""

    # The calibrated error in counts (controller_init.encoder_table; None: the sensor as it reads).
    # One attribute, one name: each name is a qstr the board keeps for good.
    _encoder_table = None

    def set_encoder_correction(self, table):
        """Subtract the encoder's calibrated error from every reading from now on (call before
        begin()): `table`, controller_init.encoder_table's for this encoder, or None."""
        self._encoder_table = table

    def _corrected(self, raw):
        """A reading in counts (the sensor's angle, or that angle unwrapped over turns) less the
        calibrated error at it; allocation-free (small ints)."""
        table = self._encoder_table
        if table is None:
            return raw
        shift = table[0]
        within = raw & (self._encoder_cpr - 1)
        i = (within >> shift) + 1
        low = table[i]
        return raw - low - (((table[i + 1] - low) * (within & ((1 << shift) - 1))) >> shift)

    def encoder_zero(self):
        """The sensor's own angle (corrected), degrees Q12 in 0..360, where angle_moved() is 0:
        the frame of the encoder correction table."""
        raise NotImplementedError

    def begin(self):
        """Power-on setup: closed-loop mode with 200 full steps, closed loop still inactive."""
        raise NotImplementedError

    def update(self):
        """Service the backend (advance the simulation, feed the step generator, read sensors)."""
        raise NotImplementedError

    def enable_closed_loop(self):
        self._closed_loop = True

    def disable_closed_loop(self):
        """Closed loop off; the PID error freezes at its last value."""
        self._closed_loop = False

    def set_control_threshold(self, usteps):
        """Re-synchronise the driver to the encoder when |error| >= usteps."""
        self._threshold = usteps

    def set_max_velocity(self, full_steps_per_s):
        raise NotImplementedError

    def set_max_acceleration(self, full_steps_per_s2):
        raise NotImplementedError

    def set_max_deceleration(self, full_steps_per_s2):
        raise NotImplementedError

    def set_rpm(self, rpm):
        """Velocity mode at `rpm` (Q16; sign is direction), ramping with the max acceleration."""
        raise NotImplementedError

    def move_steps(self, usteps):
        """Positioning mode, relative to the driver's current position."""
        raise NotImplementedError

    def move_angle(self, degrees):
        """Positioning mode, relative move of `degrees` (Q12)."""
        raise NotImplementedError

    def move_to_angle(self, degrees):
        """Positioning mode to an absolute encoder angle (degrees Q12 since home)."""
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
        """Encoder angle since home, degrees Q12."""
        raise NotImplementedError

    def encoder_rpm(self):
        raise NotImplementedError

    def driver_rpm(self):
        """Speed of the ramp generator, rpm Q16."""
        raise NotImplementedError

    def pid_error(self):
        raise NotImplementedError

    def position_reached(self):
        """True when a positioning move has arrived (False in velocity mode while moving)."""
        raise NotImplementedError

    def magnet(self):
        """The encoder magnet's health as the sensor reports it: MAGNET_OK, MAGNET_MISSING,
        MAGNET_WEAK or MAGNET_STRONG. May read the sensor over its bus (tens of microseconds):
        for the tasks (a HOME's start), not for the 1 kHz path; allocates nothing."""
        raise NotImplementedError

    def field_position(self):
        """Usteps the driver has advanced the coil field since begin(), an int wrapping at 2**30:
        the driver position without the closed loop's relabels (set_home does not reset it).
        Stall and homing evidence compare it with the encoder."""
        raise NotImplementedError
