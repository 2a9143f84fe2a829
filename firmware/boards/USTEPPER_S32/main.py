"""uStepper S32 boot: the frozen joint firmware with its configuration from flash (joint/s32/board.py)."""

from joint.s32 import board

board.run()
