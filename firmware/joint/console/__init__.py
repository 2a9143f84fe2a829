"""The serial side for a person: the debug console (debug.py) and its commands
(debug_commands.py, loaded by the first typed line), and the logger (log.py). May import core's
and detect's names, motion and micro."""
