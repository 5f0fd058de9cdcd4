# Quick start: `make demo` and `make test`. Both create .venv and install the project on first use.
PYTHON ?= $(shell command -v python3.11 2>/dev/null || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-stamp
# rl-extra (TorchRL, skrl: +42 MB, seconds to install) is in, so that `make test` runs the TorchRL
# and skrl tests (tests/ecosystem). ray (Ray RLlib 2.60: +0.55 GB, ~2 min from PyPI) is not: it pins
# gymnasium 1.2.2 (the default install has the newest), and it is the optional extra the
# issue asked for. Its tests skip without it; run them with `make EXTRAS=dev,rl,train,ifc,docs,rl-extra,ray test`
# in a fresh checkout (or a venv of their own, as docs/training.md shows).
EXTRAS ?= dev,rl,train,ifc,docs,rl-extra

.PHONY: demo test test-slow lint bench docs docs-serve detector clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[$(EXTRAS)]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/uav-struct study --out results --workers 2

test: $(STAMP)
	$(BIN)/python -m pytest -q

test-slow: $(STAMP)
	$(BIN)/python -m pytest -q -m slow

# The documentation site into site/, strict: a warning (a broken link, an undocumented env
# setting) fails the build. NO_MKDOCS_2_WARNING silences the Material theme's banner.
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict

docs-serve: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs serve

lint: $(STAMP)
	$(BIN)/ruff check uav_struct_env localization tracking tests benchmarks examples

bench: $(STAMP)  # every benchmark, on demand (minutes); figures are quoted in docs/benchmarks.md
	for b in render env_step raycast localizer wrapper_throughput detector ifc_import worker_tracking; do \
		[ -f benchmarks/$$b.py ] && $(BIN)/python benchmarks/$$b.py || exit 1; done

# The learned detector from scratch, as localization/models/MODEL_CARD.md trained it: four
# rendered datasets (~17 min; existing ones are kept), the keypoint network (42 min), then the
# patch refiner mined from that network's candidates (1.5 + 15 min), into $(DETECTOR_RUN).
# The datasets are bare sites through the ideal pinhole; the generator's --activity light|busy and
# --camera mavic2pro|mixed (lens distortion, rolling shutter, motion blur) render the real conditions.
# Evaluate the result with benchmarks/detector.py --model/--refiner and uav-struct study
# --detector learned --detector-model/--refiner-model (docs/study.md, "Evaluating retrained detector weights").
# make reruns a step only when its output is missing or older than its inputs, so each step
# replaces the folder it finds there (--overwrite): a stale or half-written earlier run.
DETECTOR_RUN ?= runs/detector
DATA := $(DETECTOR_RUN)/data
DATASET := $(BIN)/python -m uav_struct_env.datasets

detector: $(DETECTOR_RUN)/refiner/refiner.onnx

$(DATA)/keypoint_train/labels.json: | $(STAMP)
	$(DATASET) $(DATA)/keypoint_train --layouts 200 --views 15 --seed 0 --workers 2 --overwrite
$(DATA)/keypoint_val/labels.json: | $(STAMP)
	$(DATASET) $(DATA)/keypoint_val --layouts 6 --views 10 --seed 1 --overwrite
$(DATA)/refiner_train/labels.json: | $(STAMP)
	$(DATASET) $(DATA)/refiner_train --layouts 150 --views 10 --seed 3 --scale 1.0 --workers 2 --overwrite
$(DATA)/refiner_val/labels.json: | $(STAMP)
	$(DATASET) $(DATA)/refiner_val --layouts 6 --views 10 --seed 1 --scale 1.0 --overwrite

$(DETECTOR_RUN)/keypoint/model.onnx: $(DATA)/keypoint_train/labels.json $(DATA)/keypoint_val/labels.json
	$(BIN)/python -m uav_struct_env.training.train_detector --data $(DATA)/keypoint_train \
		--val $(DATA)/keypoint_val --out $(DETECTOR_RUN)/keypoint --minutes 42 --batch 16 \
		--crop 256 192 --workers 1 --threads 2 --eval-every 400 --seed 0 --overwrite

$(DETECTOR_RUN)/refiner/refiner.onnx: $(DETECTOR_RUN)/keypoint/model.onnx \
		$(DATA)/refiner_train/labels.json $(DATA)/refiner_val/labels.json
	$(BIN)/python -m uav_struct_env.training.train_refiner --data $(DATA)/refiner_train \
		--val $(DATA)/refiner_val --out $(DETECTOR_RUN)/refiner --minutes 15 --eval-every 1000 \
		--workers 1 --seed 0 --detector-model $(DETECTOR_RUN)/keypoint/model.onnx --overwrite

clean:
	rm -rf $(VENV) renders results site
