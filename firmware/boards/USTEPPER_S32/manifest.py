# The S32 image's frozen modules: exactly the files firmware/joint/boards/s32.py declares (the same
# manifest `bioscara flash` and tests/test_flash.py read), compiled at -O3 (no line numbers or
# asserts: flash is the budget, docs/s32.md), and its MAIN frozen as `main`, which runs at boot.
import os as _os
import runpy as _runpy

_JOINT = _os.path.join(_os.getcwd(), "..", "..", "joint")  # manifests run in their own folder
_board = _runpy.run_path(_os.path.join(_JOINT, "boards", "s32.py"))
_files = []
for _entry in _board["FILES"]:
    if _entry.endswith("/"):
        _files += sorted(_entry + _name for _name in _os.listdir(_os.path.join(_JOINT, _entry))
                         if _name.endswith(".py") and _entry + _name != _board["MAIN"])
    else:
        _files.append(_entry)
package("joint", files=_files, base_path=_os.path.join(_JOINT, ".."), opt=3)
module(_os.path.basename(_board["MAIN"]), base_path=_os.path.join(_JOINT, _os.path.dirname(_board["MAIN"])), opt=3)
