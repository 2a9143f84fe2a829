"""`bioscara enable [JOINT...]`."""

from .power import add_joint_argument as add_arguments, enable as run

NAME = "enable"
HELP = "enable joints with their configured currents, stall threshold and limits"
__all__ = ["NAME", "HELP", "add_arguments", "run"]
