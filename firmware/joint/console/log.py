"""Serial-console logging with levels (the original printed to Serial at 9600 baud)."""

ERROR = 0
WARN = 1
INFO = 2
DEBUG = 3
LEVEL_NAMES = ("ERROR", "WARN", "INFO", "DEBUG")


class Logger:
    """Writes `<prefix> <LEVEL> <message>` lines through `write` (print by default)."""

    def __init__(self, prefix, level=INFO, write=None):
        self.prefix = prefix
        self.level = level
        self._write = write or print

    def set_writer(self, write):
        self._write = write

    def log(self, level, msg):
        if level <= self.level:
            self._write("%s %s %s" % (self.prefix, LEVEL_NAMES[level], msg))

    def error(self, msg):
        self.log(ERROR, msg)

    def warn(self, msg):
        self.log(WARN, msg)

    def info(self, msg):
        self.log(INFO, msg)

    def debug(self, msg):
        self.log(DEBUG, msg)
