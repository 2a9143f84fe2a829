"""Command modules of the `bioscara` CLI. Each defines NAME, HELP, add_arguments(parser), run(args, session)."""

COMMANDS = ["demo", "panel", "scan", "info", "enable", "disable", "home", "move", "stop", "monitor", "plot", "shell", "flash", "sim", "console", "ports", "pins"]
