# Everything runs from a project-local virtual environment that these targets create.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test bench bench-safety derive-safety chip-costs clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/bioscara demo

test: $(STAMP)
	PATH="$(abspath $(BIN)):$$PATH" $(BIN)/python -m pytest

bench: $(STAMP)
	PATH="$(abspath $(BIN)):$$PATH" $(BIN)/python bench/run.py

bench-safety: $(STAMP)
	PATH="$(abspath $(BIN)):$$PATH" $(BIN)/python bench/safety.py

# Re-derive the joints' tracking stall-detector constants and quick-stop deceleration from the
# simulated arm (bench/derive_safety.py) and store them in firmware/joint/configs/J*.json.
derive-safety: $(STAMP)
	$(BIN)/python bench/derive_safety.py --write

# Refresh the simulator's chip cost table from the emulated chip (needs make bench-chip).
chip-costs: $(STAMP)
	$(MAKE) --no-print-directory bench-chip | tee /dev/stderr | $(BIN)/python bench/chip_costs.py

clean:
	rm -rf $(VENV) build *.egg-info
