# imcsim: every target does its own set-up on a fresh machine (idempotent).
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.imcsim-installed

.PHONY: setup data demo test lint bench bench-table2 bench-optical bench-loop bench-sweep bench-flight bench-texture-map bench-product bench-strip check-scenarios clean

setup: $(STAMP) data
	@sh scripts/ensure-llvm.sh

# user data the bundled scenarios read: the Olinda case (scenarios/olinda.yaml) from Debian's
# r-cran-stars package (apt-get download; no R needed); without apt-get: a one-line skip
data:
	@sh scripts/fetch-olinda.sh scenarios/data/olinda

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --disable-pip-version-check --upgrade pip
	$(BIN)/python -m pip install -q --disable-pip-version-check -e '.[dev]'
	@touch $(STAMP)

demo: setup
	$(BIN)/imc info
	$(BIN)/imc run scenarios/quickstart.yaml --out runs/quickstart --save-frames
	$(BIN)/imc loop scenarios/quickstart.yaml --out runs/quickstart/loop
	$(BIN)/imc run scenarios/ikonos_tdi_jitter.yaml --out runs/ikonos_tdi_jitter

test: setup
	RERUN_TELEMETRY_ENABLED=0 $(BIN)/python -m pytest -q

lint: setup
	$(BIN)/ruff check .

BENCH_STAMP := $(VENV)/.imcsim-bench

$(BENCH_STAMP): $(STAMP)
	$(BIN)/python -m pip install -q --disable-pip-version-check -e '.[dev,bench]'
	@touch $(BENCH_STAMP)

bench: setup $(BENCH_STAMP)
	$(BIN)/python benchmarks/bench_render.py
	$(BIN)/imc bench correlator

# the seed paper's Table 2 on rendered scenes (~15 min on 2 cores)
bench-table2: setup
	$(BIN)/python benchmarks/bench_table2.py

# the optical correlator emulation: accuracy vs SNR and block size, cost of each effect
bench-optical: setup
	$(BIN)/python benchmarks/bench_optical.py

# the compensation loop: every target of the loop issue (~10 min on 2 cores)
bench-loop: setup
	$(BIN)/python benchmarks/bench_loop.py

# the seed paper's airborne flight test: 9 seeded sessions + a rigid-mount one (~25 min)
bench-flight: setup
	$(BIN)/python benchmarks/bench_flight.py

# the seed paper's texture-robustness map: an 8 x 8 block map of a rendered urban scene
bench-texture-map: setup
	$(BIN)/python benchmarks/bench_texture_map.py

# the main imager's product: ground correction with and without a stage, restoration, the
# bundled scenarios' NIIRS (~15 min on 2 cores)
bench-product: setup
	$(BIN)/python benchmarks/bench_product.py

# the strip renderer: rays/s on 512^2 and 1024^2 meshes, a 2,048^2 product's time and memory
bench-strip: setup
	$(BIN)/python benchmarks/bench_strip.py

clean:
	rm -rf $(VENV) runs .pytest_cache .ruff_cache *.egg-info

# the workflow: sweep speed-up, per-point overhead, kill -9 + restart, 1,000 points (~20 min)
bench-sweep: setup
	RERUN_TELEMETRY_ENABLED=0 $(BIN)/python benchmarks/bench_sweep.py

# every bundled scenario against its expect: section, JUnit XML for CI (~4 min)
check-scenarios: setup
	RERUN_TELEMETRY_ENABLED=0 $(BIN)/imc check scenarios --junit runs/check/junit.xml --out runs/check
