# Two entry points (see README): `make demo` and `make test`.
# Each creates .venv on first use and (re)installs the project when pyproject.toml, setup.py
# or a compiled kernel's source (fe_contact/*/_kernels.pyx) changes: an editable install
# builds the kernels in place once and does not rebuild them by itself.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
OUT    ?= out
# one BLAS thread per process: the suite runs two pytest workers on two cores, and
# threaded BLAS on small dense contact matrices is slower than serial (measured 20x)
export OPENBLAS_NUM_THREADS ?= 1
export OMP_NUM_THREADS ?= 1
export MKL_NUM_THREADS ?= 1

.PHONY: demo test test-slow lint bench clean

$(STAMP): pyproject.toml setup.py $(wildcard fe_contact/*/_kernels.pyx)
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e '.[test]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/pushplan demo --out $(OUT)

# the two test workers already use both cores: no second thread in fe_contact's large dense kernels
test: $(STAMP)
	FE_CONTACT_DENSE_THREADS=1 $(BIN)/python -m pytest -n 2 --dist loadgroup -q

lint: $(STAMP)
	$(BIN)/ruff check .

test-slow: $(STAMP)
	FE_CONTACT_DENSE_THREADS=1 $(BIN)/python -m pytest -n 2 --dist loadgroup -q -m slow

bench: $(STAMP)
	for script in local_solvers paper_case planning_step scaling planner; do \
		$(BIN)/python benchmarks/$$script.py || exit 1; done
	$(BIN)/python benchmarks/tables.py   # docs/measurements.md from the new results

clean:
	rm -rf $(VENV) $(OUT) .pytest_cache .hypothesis
