# Two commands on a fresh clone:
#   make demo   set up, run `crowdcam detect` on a bundled sample set, then open the web inspector
#   make test   set up and run the test suite (what .ci/run runs)
PYTHON ?= python3
VENV   ?= .venv
PY      = $(VENV)/bin/python
SET    ?= sample_sets/tabletop_ball

.PHONY: setup browser demo test bench stress samples clean

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	# setuptools' notice on every lenient editable install (folders named like the package) is not ours to act on
	PYTHONWARNINGS="ignore:Editable installation" $(PY) -m pip install -q -e ".[test]"
	touch $@

setup: $(VENV)/.installed

demo: setup
	$(VENV)/bin/crowdcam detect $(SET)
	@echo "maps, masks and overlays are in crowdcam-out/$(notdir $(SET))/; now the web inspector (Ctrl-C stops):"
	$(VENV)/bin/crowdcam inspect $(SET)

# Debian's Chromium for the browser tests (root installs it with apt-get; never `playwright install`)
browser:
	@test -x /usr/bin/chromium || { apt-get update -qq && apt-get install -y -qq chromium >/dev/null; }
	@test -x /usr/bin/chromium || { echo "chromium is missing: apt-get install chromium (as root)"; exit 1; }

test: setup browser
	$(PY) -m pytest -q

bench: setup
	$(VENV)/bin/crowdcam bench

# ten tabs on one inspector for a minute, 404 probes, killed workers, Ctrl-C, a corrupted cache,
# a full disk: one table (bench/stress.py; a few minutes; exit 1 if a check fails)
stress: setup browser
	$(PY) -m bench.stress

samples: setup
	$(VENV)/bin/crowdcam make-samples

clean:
	rm -rf crowdcam-out .pytest_cache
