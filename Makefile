# Set-up and entry points. `make demo` and `make test` work on a fresh machine:
# they create .venv, install the package (torch pinned through constraints.txt),
# install the Debian packages offscreen rendering needs, then run.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
PIP := $(BIN)/python -m pip install --disable-pip-version-check -q -c constraints.txt

.PHONY: demo test install system-deps bench scenes clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)

$(VENV)/.installed: pyproject.toml constraints.txt | $(BIN)/python
	$(PIP) torch==2.13.0 -e .
	touch $@

$(VENV)/.installed-test: $(VENV)/.installed
	$(PIP) -e ".[test]"
	touch $@

install: system-deps $(VENV)/.installed

system-deps:
	@bash tools/install_system_deps.sh

demo: install
	$(BIN)/mjexplore scene-gen office --seed 0 --size 40x25 --out runs/demo/scene
	$(BIN)/mjexplore explore --scene runs/demo/scene --explorer gvn --seed 0 --out runs/demo/explore --video runs/demo/explore/video.mp4
	@echo "demo outputs in runs/demo/: scene/ (scene.xml, map, preview.png) and explore/ (metrics.json, video.mp4, ter.png, scene.png, ratio.png, map.png, kinematics.png, episode.mcap)"

test: system-deps $(VENV)/.installed-test
	$(BIN)/python -m pytest -n 2 --dist worksteal -q

bench: system-deps $(VENV)/.installed-test
	$(BIN)/python tools/bench_sim.py
	$(BIN)/python tools/bench_replay.py
	$(BIN)/python tools/bench_train.py
	$(BIN)/python tools/bench_render.py
	$(BIN)/python tools/bench_policy.py
	$(BIN)/python tools/bench_explorers.py

scenes: install
	$(BIN)/python tools/regenerate_scenes.py

clean:
	rm -rf $(VENV) runs .pytest_cache
