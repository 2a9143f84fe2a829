"""The one shim between MicroPython and CPython: `const`, `micropython.native`/`viper`, `ptr8`, `ptr32`.

Modules write `from ..micro import const, micropython` and then `_X = const(1)`,
`@micropython.native`: MicroPython's compiler handles `const` and the decorators by their names,
so under MicroPython they are its own; under CPython `const` returns its argument, the decorators
do nothing and the same files run as plain Python. Viper code takes `ptr8` and `ptr32` from here:
on MicroPython the viper compiler turns `ptr8(buf)` into a raw byte pointer itself (`ptr32`: 32-bit
words); under CPython it is the buffer, indexed the same way (bytes through a memoryview of their
words). `board_module` imports a board's own modules by name. Imports nothing of the firmware:
every package may import it.
"""

try:
    import micropython
    from micropython import const
except ImportError:
    class micropython:
        @staticmethod
        def native(function):
            return function

        @staticmethod
        def viper(function):
            return function

    def const(value):
        return value


def ptr8(buf):
    return buf


def ptr32(buf):
    # An int32 array is indexed by word already; bytes are seen as native-order words.
    return buf if hasattr(buf, "typecode") else memoryview(buf).cast("I")


def board_module(root, path):
    """Module `path` ("pico.motor") of the firmware package named `root` ("joint" on a board,
    "bioscara.firmware" on the host), imported by name: a board's manifest (boards/) carries only
    its own motor backend and, where there is room, the console, so shared code names them without
    importing them (the S32 image has neither pico/ nor the console)."""
    return __import__(root + "." + path, None, None, ("_",))
