# Two set-up commands (README): `make demo` and `make test`.
# Both create .venv on first use from requirements.txt (pinned, PyPI only) and install this
# package into it, editable (.venv/bin/lpv-sysid runs the working tree; `. .venv/bin/activate`
# puts it on PATH).
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
CLI    := $(VENV)/bin/lpv-sysid
STAMP  := $(VENV)/.installed
OUT    ?= demo_out

.PHONY: demo test bench clean venv

$(STAMP): requirements.txt setup.py setup.cfg
	@$(PYTHON) -c 'import sys; sys.exit(0 if sys.version_info >= (3, 10) else "lpv_sysid needs Python >= 3.10")'
	@test -x $(PY) || $(PYTHON) -m venv $(VENV) || { echo "python3 -m venv failed: install the venv module (Debian/Ubuntu: apt install python3-venv)"; exit 1; }
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -r requirements.txt
	$(PY) -m pip install --quiet --no-deps --no-build-isolation --editable .
	@touch $(STAMP)

venv: $(STAMP)

demo: $(STAMP)
	$(CLI) demo --out $(OUT)

# a sourced ROS 2's pytest plugins are switched off in setup.cfg [tool:pytest]
test: $(STAMP)
	$(PY) -m pytest -q test

bench: $(STAMP)
	$(PY) -m bench.run_all

clean:
	rm -rf $(VENV) $(OUT) .pytest_cache
