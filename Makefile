# Two commands on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
# --no-compile: byte-compiling every module of every wheel (torch's thousands) at install time costs more than the
# few a run imports; those are compiled when first imported instead (see PYC below)
PIP := $(PY) -m pip install --quiet --no-compile --constraint constraints.txt
# the test run may cache that bytecode even where the environment sets PYTHONDONTWRITEBYTECODE: the workers, the
# notebook kernels and the CLI subprocesses then compile torch's imported modules once, not once each
PYC := env -u PYTHONDONTWRITEBYTECODE
STAMP := $(VENV)/.installed

.PHONY: demo test lint bench clean

$(STAMP): pyproject.toml constraints.txt
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	# torch first, from the pinned CPU build, so nothing later can pull a CUDA wheel.
	$(PIP) "torch==2.13.0"
	$(PIP) -e ".[dev]"
	# compile what start-up imports (torch's, onnxruntime's and ours) now, once: a host that sets
	# PYTHONDONTWRITEBYTECODE would otherwise compile them from source at every start
	$(PYC) $(PY) -c "import prismstereo.cli, prismstereo.predictor, prismstereo.export, prismstereo.jobs, prismstereo.learned, prismstereo.synthetic, onnxruntime, cv2, tqdm"
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/prismstereo demo

test: $(STAMP)
	$(VENV)/bin/ruff check prismstereo tests benchmarks
	$(PYC) $(PY) -m pytest -q

lint: $(STAMP)
	$(VENV)/bin/ruff check prismstereo tests benchmarks

bench: $(STAMP)
	for b in benchmarks/[!_]*.py; do echo "== $$b"; $(PY) $$b || exit 1; done

clean:
	rm -rf $(VENV) demo_output .pytest_cache
