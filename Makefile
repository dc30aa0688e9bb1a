# Two commands matter: `make demo` and `make test`. Both create .venv and install what they need.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: install demo test lint clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	# The CPU build of torch 2.13.0 is pinned: an unpinned torch pulls several GB of CUDA wheels. No bytecode is
	# compiled at install (--no-compile): Python compiles the modules a process imports, once, instead of all of them.
	$(BIN)/pip install --quiet --no-compile "torch==2.13.0"
	$(BIN)/pip install --quiet --no-compile -e ".[test,view,sfm]"
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(BIN)/locnerf up --duration 40 --port 0 --plot out/demo/services.png

# Tests that start services or time real-time behaviour run alone, after the rest has run on two workers.
# The run starts hundreds of Python processes and collects the suite twice: bytecode and pytest's rewritten
# test modules are cached even where the environment sets PYTHONDONTWRITEBYTECODE (empty means unset).
test: export PYTHONDONTWRITEBYTECODE :=
test: $(STAMP) lint
	$(BIN)/python -m pytest -q -n 2 --dist loadfile -m "not serial"
	$(BIN)/python -m pytest -q -m serial

# Lint and format check (ruff settings in pyproject.toml).
lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

clean:
	rm -rf $(VENV) build *.egg-info

# The compose stack end to end (needs Docker with Compose v2; not part of `make test`): one image build,
# services started before their router, 150 poses read on the host, the router restarted (deploy/check_stack.sh).
.PHONY: compose-check
compose-check: $(STAMP)
	PYTHON=$(BIN)/python deploy/check_stack.sh
