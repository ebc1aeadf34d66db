# Two commands do all set-up on a fresh Debian machine with Python 3.11:
#   make demo   clean a real range scan (pymeshlab's face000.ply) with the default, render before/after/change,
#               then the paper's three filters on the noisy sample bunny (a table)
#   make test   run the test suite
# Both install the missing Debian packages, create .venv and install the package with its
# dev and bench extras (bench: the peers of benchmarks/peers.py, binary wheels) at the pinned
# versions of constraints.txt, then compile the numerical kernels once (python -m meshdenoise.warmup: the main job
# run on its scan, about 20 s), so that the first command takes the time every later one takes. A second run skips
# what is done.

PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
PYTEST_WORKERS ?= 2
# extra pytest arguments, e.g. PYTEST_ARGS='-m data' (the second pass of .ci/run); empty: the whole suite
PYTEST_ARGS ?=

.PHONY: all demo test system-deps venv clean

all: test

system-deps:
	@PY=$(PY) ./scripts/install-system-deps.sh

$(STAMP): pyproject.toml constraints.txt
	@test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --disable-pip-version-check --upgrade "pip>=23"
	$(BIN)/python -m pip install -q --disable-pip-version-check -c constraints.txt -e '.[dev,bench]'
	$(BIN)/python -m meshdenoise.warmup
	@touch $(STAMP)

venv: system-deps $(STAMP)

# the range scan pymeshlab ships (a real scanner's mesh, 85,849 vertices, open borders)
SCAN = $(shell $(BIN)/python -c "from meshdenoise.data import sample_mesh; print(sample_mesh('rangemaps/face000.ply'))")

demo: venv
	$(BIN)/meshdenoise denoise "$(SCAN)" out/demo/face000_clean.ply
	$(BIN)/meshdenoise render "$(SCAN)" out/demo/face000_clean.ply --png out/demo/face000_change.png
	$(BIN)/meshdenoise demo --out out/demo

test: venv
	$(BIN)/python -m pytest -n $(PYTEST_WORKERS) -q $(PYTEST_ARGS)

clean:
	rm -rf $(VENV) out .pytest_cache
