"""The joint's configuration: the schema, checks and loader used at boot only (schema.py), the
objects the running joint keeps (settings.py), and the shipped per-joint files J1..J4.json.
May import the pico backend's checks (boot only) and core.supervise's detector names."""
