"""Per-joint configuration files (J1..J4); one is copied to the MCU as joint_config.json."""
