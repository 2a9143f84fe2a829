"""`bioscara enable [JOINT...]`."""

from .power import add_joint_argument as add_arguments, enable as run

NAME = "enable"
HELP = "enable joints with their configured currents, stall threshold and limits"
EXAMPLES = (
    ('bioscara enable', 'every joint, with its configured currents and limits'),
    ('bioscara enable j1 j3', 'two joints'),
)
__all__ = ["NAME", "HELP", "EXAMPLES", "add_arguments", "run"]
