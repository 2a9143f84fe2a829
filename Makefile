# Everything runs from a project-local virtual environment that these targets create.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# The emulated Pico (chip/): installed only where npm exists; its tests skip without it.
NPM := $(shell command -v npm 2>/dev/null)
CHIP_STAMP := chip/node_modules/.installed
CHIP := $(if $(NPM),$(CHIP_STAMP))

.PHONY: demo test bench bench-safety derive-safety chip-costs bench-chip clean browser panel-screenshot

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

test: $(STAMP) browser $(CHIP)
	PATH="$(abspath $(BIN)):$$PATH" $(BIN)/python -m pytest

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

clean:
	rm -rf $(VENV) build *.egg-info chip/node_modules
