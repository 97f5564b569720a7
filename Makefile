# chizu — two commands on a fresh Debian machine: `make run` and `make test`.
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: run test bench docs lint install prolog browser clean image image-test

# SWI-Prolog (pyswip needs libswipl): apt swi-prolog-nox when swipl is missing.
prolog:
	@if ! command -v swipl >/dev/null 2>&1; then \
	  echo "installing swi-prolog-nox"; \
	  SUDO=$$( [ "$$(id -u)" -eq 0 ] || echo sudo ); \
	  $$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq swi-prolog-nox; \
	fi

$(STAMP): pyproject.toml
	@$(MAKE) --no-print-directory prolog
	@test -x $(PY) || $(PYTHON) -m venv $(VENV) || { \
	  echo "python3 -m venv failed: installing python3-venv"; \
	  SUDO=$$( [ "$$(id -u)" -eq 0 ] || echo sudo ); \
	  $$SUDO apt-get install -y -qq python3-venv python3-pip && $(PYTHON) -m venv $(VENV); }
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[dev,docs]'
	@touch $(STAMP)

install: prolog $(STAMP)

# the console's browser tests drive Debian's chromium (Playwright launches it by path:
# Playwright's own browser download is not needed)
browser:
	@if ! command -v chromium >/dev/null 2>&1; then \
	  echo "installing chromium"; \
	  SUDO=$$( [ "$$(id -u)" -eq 0 ] || echo sudo ); \
	  $$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq chromium; \
	fi

run: install
	$(VENV)/bin/chizu serve

# two pytest workers (pytest-xdist), one per core of the machines it runs on;
# `PYTEST_WORKERS=0 make test` runs it in one process
PYTEST_WORKERS ?= 2
test: install browser
	$(PY) -m pytest -n $(PYTEST_WORKERS)

# every benchmark, hours in all: each script writes its page docs/results/<script>.md (the
# command, date, commit, machine and its tables; tests/bench/results.py) and its raw
# outputs (json, trajectories, figures) under bench-out/
bench: install
	$(PY) tests/bench/run.py
	$(PY) tests/bench/eigenspace.py
	$(PY) tests/bench/eigenspace_unseen.py
	$(PY) tests/bench/slam.py
	$(PY) tests/bench/gated.py
	$(PY) tests/bench/slam_unseen.py
	$(PY) tests/bench/map_localization.py
	$(PY) tests/bench/merge.py
	$(PY) tests/bench/robots.py
	$(PY) tests/bench/lifelong.py
	$(PY) tests/bench/slam_stream.py
	$(PY) tests/bench/viewpoint.py
	$(PY) tests/bench/restart.py
	$(PY) tests/bench/localize_clients.py
	$(PY) tests/bench/slam_batch.py
	$(PY) tests/bench/mission.py
	$(PY) tests/bench/console.py

# the service's image (docker/Dockerfile) from CHIZU_BASE, any Debian bookworm image; the
# host's CA bundle goes to pip in the build (a proxy that re-signs TLS needs it)
CHIZU_BASE ?= debian:bookworm-slim
image:
	@if [ -f /etc/ssl/certs/ca-certificates.crt ]; then \
	  cp /etc/ssl/certs/ca-certificates.crt docker/host-ca.crt; fi
	docker build --build-arg BASE=$(CHIZU_BASE) -f docker/Dockerfile -t chizu:latest .

# the image built and its compose stack run: health, a path query, a SLAM batch on the
# Dask worker, a restart keeping the data (docker/image-test; installs Docker if missing)
image-test:
	docker/image-test

# the documentation site into site/ (mkdocs.yml); --strict: a broken link or reference
# fails it. MkDocs' plugins print a notice about a future MkDocs 2 on every build: silenced.
DOCS_ENV := NO_MKDOCS_2_WARNING=1 DISABLE_MKDOCS_2_WARNING=true
docs: install
	$(DOCS_ENV) $(VENV)/bin/mkdocs build --strict

# mypy reads the code under its installed names (chizu.numeric, chizu.service) through
# links in build/namespace (the docs build makes the same links)
lint: install
	$(VENV)/bin/ruff check numeric service tests docs/_scripts
	@mkdir -p build/namespace/chizu
	@for d in numeric service; do ln -sfn ../../../$$d build/namespace/chizu/$$d; done
	MYPYPATH=build/namespace $(VENV)/bin/mypy -p chizu.numeric -p chizu.service

clean:
	rm -rf $(VENV) var bench-out site
