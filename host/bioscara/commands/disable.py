"""`bioscara disable [JOINT...]`."""

from .power import add_joint_argument as add_arguments, disable as run

NAME = "disable"
HELP = "stop joints, zero their currents and let them freewheel"
EXAMPLES = (
    ('bioscara disable j4', 'stop j4 and let it freewheel'),
)
__all__ = ["NAME", "HELP", "EXAMPLES", "add_arguments", "run"]
