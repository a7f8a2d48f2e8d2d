# jaxpose: `make demo` and `make test` set everything up from a fresh clone.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

# robot files in joint configurations uniform over their ranges (hard poses, issue-style check)
ROBOTS := tests/fixtures/ant.xml tests/fixtures/humanoid_lite.xml tests/fixtures/quadruped.urdf \
	gymnasium:ant.xml gymnasium:humanoid.xml gymnasium:walker2d.xml

.PHONY: demo test bench paper sweep data venv clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e '.[dev]'
	touch $(STAMP)

venv: $(STAMP)

demo: $(STAMP)
	$(BIN)/python -m jaxpose.demo --out out/demo

test: $(STAMP)
	$(BIN)/python -m pytest -q -n auto --dist loadfile

bench: $(STAMP)
	$(BIN)/python experiments/bench.py
	$(BIN)/python experiments/point_budget.py
	$(BIN)/python experiments/far_bounds.py

data: $(STAMP)
	$(BIN)/python experiments/make_data.py

paper: $(STAMP)
	$(BIN)/python -m pip install -q -e '.[models]'
	$(BIN)/python experiments/paper_table.py
	$(BIN)/python experiments/mujoco_views.py
	$(BIN)/python experiments/mujoco_views.py --models $(ROBOTS) --spread uniform --views 20 --seed 1 \
		--plots 2 --out experiments/results/mujoco_views_uniform
	$(BIN)/python experiments/hard_poses.py
	$(BIN)/python experiments/track_table.py
	$(BIN)/python experiments/mujoco_track.py

sweep: $(STAMP)
	$(BIN)/python experiments/sweep_population.py

clean:
	rm -rf out data experiments/results/runs
