"""The joint's validated configuration as the running firmware keeps it.

config.py reads and validates the file at boot and builds these objects; the board then forgets
config.py (its schema, defaults and checks: about 9 KB of heap, startup.drop_boot_only). Only these
small classes stay, since the controller and the console keep the configuration.
"""

CONFIG_FILE = "joint_config.json"
JOINTS = ("J1", "J2", "J3", "J4")


class Section:
    """Attribute view of one validated config section."""

    def __init__(self, values):
        for key in values:
            setattr(self, key, values[key])


class JointConfig:
    def __init__(self, source):
        self.source = source
        self.errors = []
        self.joint = None
        self.address = None
        self.deadman_ms = 50
        self.motor = {"backend": "sim"}

    @property
    def valid(self):
        return not self.errors

    @property
    def joint_id(self):
        return JOINTS.index(self.joint) + 1 if self.joint in JOINTS else 0
