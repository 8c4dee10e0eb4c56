PY := .venv/bin/python
export OMP_NUM_THREADS ?= 1

.PHONY: setup demo test test-fast lint bench clean

setup:
	@bash scripts/setup

demo: setup
	$(PY) -m lbshape.cli demo --out demo-output

test: setup
	$(PY) -m pytest -q tests

test-fast: setup
	$(PY) -m pytest -q -m "not slow and not mpi" tests

lint: setup
	$(PY) -m ruff check lbshape tests scripts meshes

bench: setup
	$(PY) scripts/bench_all.py

clean:
	rm -rf .venv build *.egg-info .pytest_cache demo-output
