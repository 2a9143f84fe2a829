"""`bioscara disable [JOINT...]`."""

from .power import add_joint_argument as add_arguments, disable as run

NAME = "disable"
HELP = "stop joints, zero their currents and let them freewheel"
__all__ = ["NAME", "HELP", "add_arguments", "run"]
