# Everything runs from a project-local virtual environment that these targets create.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# The emulated Pico (chip/): installed only where npm exists; its tests skip without it.
NPM := $(shell command -v npm 2>/dev/null)
CHIP_STAMP := chip/node_modules/.installed
CHIP := $(if $(NPM),$(CHIP_STAMP))

.PHONY: demo test docs bench bench-safety derive-safety chip-costs bench-chip clean browser panel-screenshot \
	s32-toolchain s32-image s32-emu bench-s32

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

$(CHIP_STAMP): chip/package.json chip/package-lock.json
	npm ci --prefix chip --no-audit --no-fund --loglevel=error
	touch $(CHIP_STAMP)

demo: $(STAMP)
	$(BIN)/bioscara demo

test: $(STAMP) browser $(CHIP) s32-image s32-emu
	PATH="$(abspath $(BIN)):$$PATH" $(BIN)/python -m pytest

# The documentation site, offline, into site/ (strict: a warning fails it; docgen/ draws the pictures).
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/python -m mkdocs build --strict --quiet

bench: $(STAMP)
	PATH="$(abspath $(BIN)):$$PATH" $(BIN)/python bench/run.py

bench-safety: $(STAMP)
	PATH="$(abspath $(BIN)):$$PATH" $(BIN)/python bench/safety.py

# Re-derive the joints' tracking stall-detector constants and quick-stop deceleration from the
# simulated arm (bench/derive_safety.py) and store them in firmware/joint/config/J*.json.
derive-safety: $(STAMP)
	$(BIN)/python bench/derive_safety.py --write

# Refresh the simulator's chip cost table from the emulated chip (needs make bench-chip).
chip-costs: $(STAMP)
	$(MAKE) --no-print-directory bench-chip | tee /dev/stderr | $(BIN)/python bench/chip_costs.py

# The panel's web test drives Debian's chromium; install it where this machine lets us (root, apt).
browser:
	@command -v chromium >/dev/null 2>&1 || { [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1 && \
	  { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null; } || \
	  echo "chromium is not installed: the panel's browser test will be skipped"; }

panel-screenshot: $(STAMP)
	$(BIN)/python -m bioscara.panel.screenshot docs/panel.svg

# Figures measured on the emulated Pico (needs node and ../shared/rp2040; says what is missing).
bench-chip: $(STAMP) $(CHIP)
	PATH="$(abspath $(BIN)):$$PATH" $(BIN)/python bench/chip_bench.py

# The uStepper S32 image (docs/s32.md): MicroPython v1.28.0's stm32 port from ../shared/stm32, built
# offline with Debian's gcc-arm-none-eabi (installed where this machine lets us, as chromium is),
# the joint firmware frozen in by firmware/boards/USTEPPER_S32/manifest.py. Result:
# build/s32/firmware.{bin,dfu,elf}; never committed. Without the source or the compiler: a message.
S32_TARBALL := ../shared/stm32/micropython-v1.28.0-stm32-src.tar.xz
S32_TREE := build/micropython-v1.28.0
S32_BOARD := $(abspath firmware/boards/USTEPPER_S32)
S32_FLAGS := BOARD_DIR=$(S32_BOARD) FROZEN_MANIFEST=$(S32_BOARD)/manifest.py BUILD=$(abspath build/s32) \
	MICROPY_GIT_TAG=v1.28.0 MICROPY_GIT_HASH=e0e9fbb17e

s32-toolchain:
	@command -v arm-none-eabi-gcc >/dev/null 2>&1 || { [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1 && \
	  { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq gcc-arm-none-eabi \
	    libnewlib-arm-none-eabi >/dev/null; } || \
	  echo "arm-none-eabi-gcc is not installed (apt-get install gcc-arm-none-eabi libnewlib-arm-none-eabi): no S32 image"; }

s32-image: s32-toolchain
	@if [ ! -f $(S32_TARBALL) ]; then echo "$(S32_TARBALL) is missing: no S32 image"; \
	elif ! command -v arm-none-eabi-gcc >/dev/null 2>&1; then echo "arm-none-eabi-gcc is missing: no S32 image"; \
	else mkdir -p build && { [ -d $(S32_TREE) ] || tar -xJf $(S32_TARBALL) -C build; } && \
	  $(MAKE) -C $(S32_TREE)/mpy-cross -j2 --no-print-directory >/dev/null && \
	  SOURCE_DATE_EPOCH=1775481169 $(MAKE) -C $(S32_TREE)/ports/stm32 -j2 --no-print-directory $(S32_FLAGS) && \
	  ls -l build/s32/firmware.bin build/s32/firmware.dfu; fi

# Qiling boots the S32 image for bench-s32's heap figure (tests/s32_emu.py), in an environment of
# its own: it pins unicorn 2.0.1.post1, and its dependencies stay out of the project's.
S32_EMU := build/qiling-venv/.installed
# A failed install leaves no environment: the emulated-S32 tests then skip, naming it.
$(S32_EMU):
	@$(PYTHON) -m venv build/qiling-venv && \
	  build/qiling-venv/bin/python -m pip install --quiet qiling==1.4.6 unicorn==2.0.1.post1 && touch $@ || \
	  { rm -rf build/qiling-venv; echo "Qiling could not be installed: no emulated S32"; }

s32-emu: $(S32_EMU)

# Flash and heap figures of the S32 image (builds it first; says what is missing).
bench-s32: $(STAMP) s32-image s32-emu
	$(BIN)/python bench/s32_image.py build/s32

clean:
	rm -rf $(VENV) build site *.egg-info chip/node_modules
