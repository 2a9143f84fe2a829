# uStepper S32 (STM32F401RCT6: 256 KB flash, 64 KB RAM) for MicroPython v1.28.0's stm32 port,
# built out of tree: make -C ports/stm32 BOARD_DIR=<this folder> FROZEN_MANIFEST=<manifest.py>.
MCU_SERIES = f4
CMSIS_MCU = STM32F401xC
AF_FILE = boards/stm32f401_af.csv
# Our own memory map (no upstream script has 256 KB / 64 KB F401 parts), used with the port's
# layout for images without a filesystem: vectors, code and data all from 0x08000000.
LD_FILES = $(BOARD_DIR)/ustepper_s32.ld boards/common_basic.ld
TEXT0_ADDR = 0x08000000

# No filesystem (its 16 KB RAM sector cache would take a quarter of the RAM): the joint firmware
# is frozen into the image and its configuration lives in the last flash sector's tail.
MICROPY_VFS_FAT = 0
MICROPY_VFS_LFS1 = 0
MICROPY_VFS_LFS2 = 0

# Flash is the scarce resource: link-time optimisation and no optional C modules.
LTO = 1
MICROPY_PY_SSL = 0
MICROPY_PY_NETWORK = 0
MICROPY_PY_BTREE = 0
