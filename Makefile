# Set-up and common jobs. `make demo` and `make test` install everything on a fresh machine first.
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)
DEMO_ARGS ?=
# Parallel test workers, one torch thread each (sized for a two-core machine; more pay little, the
# orientation learning test alone takes most of the run).
TEST_WORKERS ?= 2

.PHONY: install demo lint test test-all bench clean

$(STAMP): pyproject.toml
	@# open3d links against libusb-1.0, which slim Debian/Ubuntu images lack.
	@ldconfig -p | grep -q libusb-1.0 || ($(SUDO) apt-get update -qq && $(SUDO) apt-get install -y -qq libusb-1.0-0)
	@test -x $(PY) || python3 -m venv $(VENV)
	@# uv fetches in parallel: the CUDA build of torch that LeRobot's pin takes from PyPI (about 4 GB)
	@# installs in about a minute instead of pip's three to four, most of a fresh clone's CI. Bytecode is
	@# compiled here, as pip does, since every command imports torch and LeRobot anew and some machines
	@# set PYTHONDONTWRITEBYTECODE (imports then take 11 s instead of 5).
	$(PY) -m pip install -q uv
	$(VENV)/bin/uv pip install -q --compile-bytecode --python $(PY) -e ".[test]"
	@touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/taxdpd-demo $(DEMO_ARGS)

lint: $(STAMP)
	$(VENV)/bin/ruff check .

test: lint
	$(PY) -m pytest -n $(TEST_WORKERS) --dist worksteal

test-all: $(STAMP)
	$(PY) -m pytest -m "slow or not slow"

bench: $(STAMP)
	$(PY) benchmarks/speed.py

clean:
	rm -rf outputs results .pytest_cache
