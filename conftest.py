"""The firmware loads once in the tests: `joint.X` (the name the board and the firmware tests use)
is the very module `bioscara.firmware.X` (the host's), so there is one `protocol` module, one
`Register` class, one `JointController`. Under the MicroPython unix port the tests import the
firmware as `joint` directly (firmware/tests/mprun.py); this hook is CPython's only."""

import importlib
import importlib.abc
import importlib.util
import sys

CANONICAL = "bioscara.firmware"
ALIAS = "joint"


class _FirmwareAlias(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Finds `joint` and `joint.*` as the already-importable `bioscara.firmware` modules."""

    def find_spec(self, name, path=None, target=None):
        if name == ALIAS or name.startswith(ALIAS + "."):
            return importlib.util.spec_from_loader(name, self)
        return None

    def __init__(self):
        self._canonical = {}

    def create_module(self, spec):
        module = importlib.import_module(CANONICAL + spec.name[len(ALIAS):])
        self._canonical[spec.name] = module.__spec__
        return module

    def exec_module(self, module):
        # Executed once already, under its canonical name; the import system has just set the
        # alias's spec on it, and importlib.resources (flash) reads packages by their spec.
        module.__spec__ = self._canonical.pop(module.__spec__.name)


sys.meta_path.insert(0, _FirmwareAlias())
