"""Run firmware test modules under the MicroPython unix port.

    MICROPYPATH=firmware:firmware/tests micropython firmware/tests/mprun.py test_stall ...

Each module's `test_*` functions run in name order; the exit status is the number of failures.
pytest runs the same modules under CPython (tests/test_firmware_on_micropython.py runs this).
"""

import sys


def run(module_name):
    module = __import__(module_name)
    failures = 0
    for name in sorted(n for n in dir(module) if n.startswith("test_")):
        try:
            getattr(module, name)()
            print("PASS %s.%s" % (module_name, name))
        except Exception as exc:
            failures += 1
            print("FAIL %s.%s" % (module_name, name))
            sys.print_exception(exc)
    return failures


def main(argv):
    failures = 0
    for module_name in argv:
        failures += run(module_name)
    print("%d failure(s)" % failures)
    sys.exit(1 if failures else 0)


main(sys.argv[1:])
