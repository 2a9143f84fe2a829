"""The uStepper S32 image's /main.py (frozen as `main`): the joint firmware with its configuration
from flash (s32/board.py). Not imported by the package."""

from joint.s32 import board

board.run()
