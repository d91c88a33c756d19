# Two commands on a fresh machine: `make demo` and `make test`. Both set up what they need.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.deepslam-installed
export MUJOCO_GL ?= egl
export PYOPENGL_PLATFORM ?= egl
# Keep two cores busy but not oversubscribed.
export OMP_NUM_THREADS ?= 2
# Shared cores: let idle OpenMP threads sleep instead of spinning.
export OMP_WAIT_POLICY ?= PASSIVE

.PHONY: setup demo test bench bench-speed results readme-check clean

setup: $(STAMP)

# torch first, from its CPU wheel (on this machine's kind `pip install torch==2.13.0` finds it on disk; elsewhere
# `make setup TORCH_INDEX=--index-url=https://download.pytorch.org/whl/cpu`), so that nothing pulls CUDA builds;
# then the package with every extra at the exact versions it is tested with (constraints.txt, docs/install.md).
TORCH_INDEX ?=
$(STAMP): pyproject.toml constraints.txt scripts/apt-deps.sh
	bash scripts/apt-deps.sh
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q $(TORCH_INDEX) -c constraints.txt torch
	$(PY) -m pip install -q -c constraints.txt -e '.[all]'
	touch $(STAMP)

demo: $(STAMP)
	$(PY) -m deepslam.studies.demo

test: $(STAMP)
	$(PY) -m pytest -q -n 2 --dist loadfile

# Every figure of the issues: speed against same-run baselines (bench.run, about 5 minutes) and the
# accuracy tables (SLAM vs VO on street and room, about 5 minutes; synthetic vs supervised training
# over 3 seeds, about 25 minutes). All resumable: outputs that exist are reused.
bench: bench-speed results

bench-speed: $(STAMP)
	$(PY) -m bench.run

results: $(STAMP)
	$(PY) -m bench.results_slam
	$(PY) -m bench.results_keyframes
	$(PY) -m bench.results_width
	$(PY) -m bench.results_vo
	$(PY) -m bench.results_repro
	$(PY) -m bench.results_repro_rgbd
	$(PY) -m bench.results_lever
	$(PY) -m bench.results_layout
	$(PY) -m bench.results_claim
	$(PY) -m bench.results_exact_model
	$(PY) -m bench.results_extra
	$(PY) -m bench.results_speed
	$(PY) -m bench.results_road
	$(PY) -m bench.results_real
	$(PY) -m bench.results_turn
	$(PY) -m bench.results_tum
	$(PY) -m bench.results_flow
	$(PY) -m bench.results_stress
	$(PY) -m bench.results_agreement
	$(PY) -m bench.results_adapt
	$(PY) -m bench.results_doc

# Every command of the README's examples block, in order, in a temporary folder: exit status and wall
# time of each against the time the README states (out/readme_check.md). Not part of `make test`.
readme-check: $(STAMP)
	$(PY) scripts/readme_check.py

clean:
	rm -rf out build *.egg-info
