"""`micropython.native` and `micropython.viper` under both interpreters. MicroPython's compiler handles the decorator by
its name, so modules write `@micropython.native` after `from .emitters import micropython`; under
CPython the decorator does nothing and the same files run as plain Python."""

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
