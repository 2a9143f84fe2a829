"""Bioscara host package: bus transports, joints, gripper, arm, simulator and tools."""

__version__ = "0.1.0"
