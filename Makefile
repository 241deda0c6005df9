# One-command entry points. Each target creates .venv and installs the project on first use.
# Another interpreter in its own venv (Python 3.10 to 3.12 are supported; .ci/run does this for 3.10 and 3.12):
#   make PYTHON=python3.12 VENV=/tmp/venv-3.12 test-fast
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
BACKEND ?= pivot
POSE ?= topic

.PHONY: demo test test-fast lint bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[test,plot,record,bench,mavlink,dynamixel,pcd]'
	touch $(STAMP)

# `make demo BACKEND=mavlink` (or dynamixel): the same run against that backend's simulator.
# `make demo POSE=tf` (or tf-static): the daemon takes the pose from /tf and /tf_static instead of /odom.
demo: $(STAMP)
	$(BIN)/python tools/demo.py --backend $(BACKEND) --pose $(POSE)

test: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/python -m pytest -q

# Everything except the tests marked slow (subprocesses, real time): the edit-test loop, about 45 s.
test-fast: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/python -m pytest -q -m "not slow"

# ruff over the whole tree (the check `make test` starts with).
lint: $(STAMP)
	$(BIN)/ruff check .

bench: $(STAMP)
	$(BIN)/pivotd bench montecarlo --quick

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .ruff_cache
