"""Joint units <-> actuator units, in one place.

The wire carries what the motor sees (degrees, RPM); the host API speaks joint units (rad for
revolute joints, m for prismatic ones) through `actuator = reduction * (joint - offset)`, with the
reduction in rad of motor per joint unit. Its sign encodes the mounting direction. Velocities and
accelerations use the reduction only; motion limits use |reduction| (the original sent J2's
limits negative, bug 9.2.5).
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class Transmission:
    reduction: float
    offset: float = 0.0

    def __post_init__(self) -> None:
        if not math.isfinite(self.reduction) or self.reduction == 0:
            raise ValueError(f"reduction must be finite and non-zero, got {self.reduction}")

    def with_offset(self, offset: float) -> Transmission:
        return Transmission(self.reduction, offset)

    def motor_degrees(self, position: float) -> float:
        """Joint position -> motor angle, degrees."""
        return math.degrees(self.reduction * (position - self.offset))

    def position(self, motor_degrees: float) -> float:
        """Motor angle, degrees -> joint position."""
        return math.radians(motor_degrees) / self.reduction + self.offset

    def motor_rpm(self, velocity: float) -> float:
        """Joint velocity (units/s) -> motor RPM."""
        return math.degrees(self.reduction * velocity) / 6.0

    def velocity(self, motor_rpm: float) -> float:
        """Motor RPM -> joint velocity (units/s)."""
        return math.radians(motor_rpm) * 6.0 / self.reduction

    def motor_limit(self, joint_rate: float) -> float:
        """A velocity (units/s) or acceleration (units/s^2) limit -> motor deg/s or deg/s^2, positive."""
        return math.degrees(abs(self.reduction) * joint_rate)
