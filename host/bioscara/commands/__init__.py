"""Command modules of the `bioscara` CLI. Each defines NAME, HELP, EXAMPLES, add_arguments(parser), run(args, session).

EXAMPLES are (command line, what it does) pairs: `bioscara COMMAND --help` prints them and the
documentation's command reference (docgen/cli_reference.py) shows them; a command without one
fails the docs build. The modules may import the rest of `bioscara`, never each other except
`options` (argument types) and `power` (enable and disable share it).
"""

COMMANDS = ["demo", "panel", "scan", "info", "enable", "disable", "home", "move", "calibrate", "stop", "monitor", "plot", "shell", "flash", "sim", "console", "ports", "pins"]
