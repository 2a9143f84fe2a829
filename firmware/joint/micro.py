"""`micropython.native` and `micropython.viper` under both interpreters. MicroPython's compiler
handles the decorators by their names, so modules write `@micropython.native` after
`from .emitters import micropython`; under CPython the decorators do nothing and the same files run
as plain Python. Viper code takes `ptr8` and `ptr32` from here: on MicroPython the viper compiler turns
`ptr8(buf)` into a raw byte pointer itself (`ptr32`: 32-bit words); under CPython it is the buffer, indexed the same way (bytes
through a memoryview of their words)."""

try:
    import micropython
except ImportError:
    class micropython:
        @staticmethod
        def native(function):
            return function

        @staticmethod
        def viper(function):
            return function


def ptr8(buf):
    return buf


def ptr32(buf):
    # An int32 array is indexed by word already; bytes are seen as native-order words.
    return buf if hasattr(buf, "typecode") else memoryview(buf).cast("I")


def state_word(i):
    """A property over word i of the instance's int32 state array `s`: viper code works on the
    array, Python code off the 1 kHz path uses the names."""
    def get(self):
        return self.s[i]

    def put(self, value):
        self.s[i] = value
    return property(get, put)
