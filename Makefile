# Set up and run factory on a fresh machine: `make demo` plans every sample part into build/ and runs
# the sample orders through the cell (build/cell.mcap + build/cell.layout.json for Foxglove);
# `make test` runs the test suite. Both create .venv and install factory into it first.

PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
ROS2_VENV := .venv-ros2
OUT    := build
PARTS  := $(basename $(notdir $(wildcard samples/*.stl)))

.PHONY: demo plans warm test explore bench venv clean

# The parts are planned in parallel, one per core this machine has, each printing one line as it finishes.
# The sub-make gets no install rule (SUBMAKE): `demo` has installed, and `make -o $(BIN)/.installed demo`
# (never reinstall) is not passed down to a sub-make, which would otherwise reinstall into the venv.
JOBS ?= $(shell nproc 2>/dev/null || echo 2)
demo: $(BIN)/.installed
	@$(MAKE) --no-print-directory -j$(JOBS) plans SUBMAKE=1
	$(BIN)/python samples/summarize.py $(PARTS:%=$(OUT)/%.plan.json)
	$(BIN)/factory simulate samples/orders.yaml --catalog $(OUT) --mcap $(OUT)/cell.mcap --overwrite \
	    || test $$? -eq 3  # 3: simulated and written, an order not done (see its reason)

# The sample relief is generated: an open heightfield sheet, planned as a relief (cadcam/relief.py).
samples/relief.stl: samples/make_relief.py | $(BIN)/.installed
	$(BIN)/python samples/make_relief.py

# The cell's roadmap first, beside the largest plan (a fresh machine builds it once, in about 25 s of one
# core; a plan that reaches its robot stage before it is built waits for it, then reads it), then the
# other files largest first: the longest plans start first, so no long one starts last and runs alone.
plans: warm $(addsuffix .plan.json,$(addprefix $(OUT)/,$(basename $(notdir $(shell ls -S samples/*.stl)))))

warm: $(BIN)/.installed
	@$(BIN)/factory cell warm fixtures/cell.yaml

# One part per rule, so `make -j` plans parts in parallel; 3: written, verify failed (its line says so).
$(OUT)/%.plan.json: samples/%.stl $(BIN)/.installed
	@echo "planning $* ..."
	@$(BIN)/factory plan $< -o $(OUT) --overwrite --quiet || test $$? -eq 3
	@$(BIN)/python samples/summarize.py --line $@

test: $(BIN)/.installed $(ROS2_VENV)/.installed
	$(BIN)/python -m pytest -q -n auto --dist loadfile

# The property tests with fresh random examples (the suite's are fixed): run it to look for new failures.
explore: $(BIN)/.installed $(ROS2_VENV)/.installed
	HYPOTHESIS_PROFILE=explore $(BIN)/python -m pytest -q -n auto --dist loadfile -m hypothesis

# A real ROS 2 node for tests/factory/test_ros2.py (rclpy and message wheels of Jazzy), in its own
# environment: its rosidl_parser brings lark-parser, whose `lark` module would replace the tests' lark.
$(ROS2_VENV)/.installed: tests/ros2node-requirements.txt
	$(PYTHON) -m venv $(ROS2_VENV)
	$(ROS2_VENV)/bin/python -m pip install --quiet --upgrade pip
	$(ROS2_VENV)/bin/python -m pip install --quiet -r tests/ros2node-requirements.txt
	touch $@

# Speed against OpenCAMLib (a benchmark-only extra) and every CAM stage; prints JSON last lines.
bench: $(BIN)/.installed
	$(BIN)/python -m pip install --quiet -e '.[bench]'
	$(BIN)/python benchmarks/finishing_vs_ocl.py --json
	$(BIN)/python benchmarks/cam_pipeline.py --json

venv: $(BIN)/.installed

ifndef SUBMAKE
$(BIN)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $@
endif

clean:
	rm -rf $(OUT)
