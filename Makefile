# Two commands on a fresh machine (README): `make demo` and `make test`; `make test-fast` while
# editing.
# Both create the virtual environment from PyPI (pinned versions) if it is not there.

PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
ROBOTS_STAMP := $(VENV)/.robots-installed
SCHEME ?= adaptive_impedance
ROBOT ?=
DURATION ?= 10
MODE ?= realtime
OUT ?= sessions
DEMO_ARGS ?=

.PHONY: demo test test-fast lint benchmark fuzz venv clean

venv: $(STAMP)

## The robots' URDFs (example-robot-data, 131 MB): for ROBOT=... and the tests.
$(ROBOTS_STAMP): $(STAMP) requirements-robots.txt
	$(BIN)/pip install --quiet -r requirements-robots.txt -c constraints.txt
	touch $(ROBOTS_STAMP)

$(STAMP): requirements.txt constraints.txt setup.py
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -r requirements.txt -c constraints.txt
	$(BIN)/pip install --quiet --no-deps -e .
	touch $(STAMP)

## A recorded, analysed 10 s session: plant, controller and recorder over ROS 2 at 1 kHz;
## ROBOT=panda (or ur5): the scheme on that arm's URDF, wiping a table.
demo: $(STAMP) $(if $(ROBOT),$(ROBOTS_STAMP))
	$(BIN)/python -m cr_control.tools.warm_up $(SCHEME)
	$(BIN)/cr_session --scheme $(SCHEME) --duration $(DURATION) --mode $(MODE) --out $(OUT) $(if $(ROBOT),--robot $(ROBOT)) $(DEMO_ARGS)

## Python writes its bytecode caches (__pycache__, ignored by git) for the project and the tests:
## an environment that forbids it (PYTHONDONTWRITEBYTECODE) would have every process of the suite
## compile them again.
unexport PYTHONDONTWRITEBYTECODE

## The suite on both cores: a module whole on one worker, the Ray modules on one (test/conftest.py).
## Three workers for the whole suite: its ROS tests wait on processes and messages for about
## a quarter of their time, which a third worker fills (measured: four ROS modules 89 s with
## 2 workers, 78 s with 3; the whole suite on a fresh clone 14:00-14:13, 14:25 with 2 on a
## quiet day before: the machine is busy either way); the fast tier is all computation, two.
PYTEST := $(BIN)/python -m pytest -q --dist loadscope

## Lint, the import contracts (.importlinter, docs/architecture.md), compile the kernels once
## (numba caches them beside the sources), the whole test suite.
test: $(STAMP) $(ROBOTS_STAMP)
	$(BIN)/ruff check .
	$(BIN)/lint-imports --no-cache
	$(BIN)/python -m cr_control.tools.warm_up
	$(PYTEST) -n 3 --durations=30 test

## The same without the tests that start ROS or Ray (marked `ros`) and the long offline studies'
## matrices beyond a sample (marked `slow`, test/conftest.py): under 2 min.
test-fast: $(STAMP) $(ROBOTS_STAMP)
	$(BIN)/ruff check .
	$(BIN)/lint-imports --no-cache
	$(BIN)/python -m cr_control.tools.warm_up
	$(PYTEST) -n 2 -m "not ros and not slow" test

## Real-time figures and their targets (PASS/FAIL): sessions across processes, composed and
## with the recorder vs a bare rclpy echo pair, the recorder's CPU per message, lockstep and
## offline speed, costs carried to the "before" table's machine by that code run beside ours
## (and by a loop calibration). Three ABBA repeats per pair (disturbed pairs run again),
## 6-12 min; BENCH_ARGS e.g. "--repeat 1 --duration 5 --skip-lockstep" for a quick look.
BENCH_ARGS ?= --repeat 3
BENCH_JSON ?= $(OUT)/benchmark.json
benchmark: $(STAMP) $(ROBOTS_STAMP)
	$(BIN)/cr_benchmark --json $(BENCH_JSON) $(BENCH_ARGS)

## Hostile and careless input: the tools alone (robot descriptions, files, command lines;
## --suite inputs, ~1 min) and recorded real-time sessions, one row per case (alive, finite,
## max |q'|, max |f|, safe stop, resumed, verdict): suites session (thesis arm) and robot
## (panda_ft), ~10 min; delay (panda_ft behind a delayed, bursty driver, ~2 min), position
## (ur5_position, ~3 min), gains and gains_impedance (panda, gains at their accepted
## extremes, ~3 min each); ~20 min in all. FUZZ_ARGS e.g. "--suite delay,position" or
## "--cases huge_joint_state,second_commander".
FUZZ_ARGS ?=
fuzz: $(STAMP)
	$(BIN)/python -m cr_control.tools.warm_up adaptive_impedance impedance
	$(BIN)/python -m cr_control.tools.fuzz $(FUZZ_ARGS)

clean:
	rm -rf $(VENV) build install log *.egg-info
