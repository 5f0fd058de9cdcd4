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
EXTRAS ?= dev,rl,train,ifc,docs,rl-extra,photo

.PHONY: demo test test-slow lint bench docs docs-serve detector clean distclean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[$(EXTRAS)]'
	touch $(STAMP)

# A second `make demo` replaces the first's results/ (and says so); `--out` elsewhere keeps both.
demo: $(STAMP)
	@if [ -e results ]; then echo "make demo: replacing the earlier results in results/"; fi
	$(BIN)/uav-struct study --out results --workers 2 --overwrite

# The default suite in parallel, one pytest-xdist worker per core (-n auto; an idle worker takes
# tests queued on the other, --dist worksteal); test-slow: the long runs.
test: $(STAMP)
	$(BIN)/python -m pytest -q -n auto --dist worksteal

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
	for b in render env_step raycast localizer wrapper_throughput warm_start detector ifc_import worker_tracking; do \
		[ -f benchmarks/$$b.py ] && $(BIN)/python benchmarks/$$b.py || exit 1; done

# The active-site detector (localization/detect/models/landmarks_active_v2.onnx +
# landmarks_active_v4_refiner.onnx, the pair landmarks_active_v4) from scratch, as
# localization/detect/models/MODEL_CARD.md ("landmarks_active_v4") trained it: seven
# rendered datasets (~35 min; existing ones are kept), the keypoint network (42 min), then two
# patch refiners mined from that network's candidates (~2-4 min each) and trained over 25,000
# steps each (~34 and ~37 min alone; a step budget, so a shared machine only makes it slower):
# the first on the six mixed datasets (landmarks_active_v3's refiner), the second on those and a
# busy-site set through the Mavic; the committed refiner is the two averaged into one ONNX file
# (python -m uav_struct_env.training.ensemble), into $(DETECTOR_RUN)/refiner.onnx.
# The data is what an active site through a real camera looks like: site activity none, light and
# busy in turn over the layouts (--activity mixed) and every other image through the Mavic 2 Pro
# preset (--camera mixed: lens distortion, rolling shutter, motion blur), every other pair of images
# through the camera imaging (--imaging mixed: optics blur, sensor noise, JPEG), on random sites and on
# the duplex IFC building (tests/data/ifc/duplex.ifc, at its stages). The default weights
# landmarks_v1 were trained with the same commands on bare sites through the pinhole
# (DATASET without --activity/--camera, 200x15 + 6x10 and 150x10 + 6x10 images, no IFC sets) and a
# 15-minute refiner budget (--minutes 15, no --max-steps), as the active pairs v1 and v2, whose
# files no longer ship: MODEL_CARD.md ("Rebuilding the superseded weights") gives their commands,
# and v3's refiner is the first member of the committed v4 refiner (ensemble --split).
# Evaluate the result with benchmarks/detector.py --model/--refiner and uav-struct study
# --detector learned --detector-model/--refiner-model (docs/study.md, "Evaluating retrained detector weights").
# make reruns a step only when its output is missing or older than its inputs, so each step
# replaces the folder it finds there (--overwrite): a stale or half-written earlier run.
DETECTOR_RUN ?= runs/detector
DATA := $(DETECTOR_RUN)/data
DATASET := $(BIN)/python -m uav_struct_env.datasets --activity mixed --camera mixed --imaging mixed --overwrite
IFC_BUILDING := tests/data/ifc/duplex.ifc
KEYPOINT_DATA := $(DATA)/keypoint_train $(DATA)/keypoint_ifc
REFINER_DATA := $(DATA)/refiner_train $(DATA)/refiner_ifc

REFINER_ARGS := --val $(DATA)/refiner_val --minutes 120 --max-steps 25000 --eval-every 1000 \
	--workers 1 --seed 0 --detector-model $(DETECTOR_RUN)/keypoint/model.onnx --overwrite

detector: $(DETECTOR_RUN)/refiner.onnx

$(DATA)/keypoint_train/labels.json: | $(STAMP)
	$(DATASET) $(DATA)/keypoint_train --layouts 200 --views 15 --seed 0 --workers 2
$(DATA)/keypoint_ifc/labels.json: | $(STAMP)
	$(DATASET) $(DATA)/keypoint_ifc --site $(IFC_BUILDING) --layouts 30 --views 15 --seed 5 --workers 2
$(DATA)/keypoint_val/labels.json: | $(STAMP)
	$(DATASET) $(DATA)/keypoint_val --layouts 9 --views 10 --seed 1 --workers 2
$(DATA)/refiner_train/labels.json: | $(STAMP)
	$(DATASET) $(DATA)/refiner_train --layouts 150 --views 10 --seed 3 --scale 1.0 --workers 2
$(DATA)/refiner_ifc/labels.json: | $(STAMP)
	$(DATASET) $(DATA)/refiner_ifc --site $(IFC_BUILDING) --layouts 21 --views 10 --seed 6 --scale 1.0 --workers 2
$(DATA)/refiner_val/labels.json: | $(STAMP)
	$(DATASET) $(DATA)/refiner_val --layouts 9 --views 10 --seed 1 --scale 1.0 --workers 2
$(DATA)/refiner_busy/labels.json: | $(STAMP)
	$(BIN)/python -m uav_struct_env.datasets --activity busy --camera mavic2pro --imaging mixed --overwrite \
		$(DATA)/refiner_busy --layouts 150 --views 10 --seed 7 --scale 1.0 --workers 2

$(DETECTOR_RUN)/keypoint/model.onnx: $(KEYPOINT_DATA:%=%/labels.json) $(DATA)/keypoint_val/labels.json
	$(BIN)/python -m uav_struct_env.training.train_detector --data $(KEYPOINT_DATA) \
		--val $(DATA)/keypoint_val --out $(DETECTOR_RUN)/keypoint --minutes 42 --batch 16 \
		--crop 256 192 --workers 1 --threads 2 --eval-every 400 --seed 0 --overwrite

$(DETECTOR_RUN)/refiner/refiner.onnx: $(DETECTOR_RUN)/keypoint/model.onnx \
		$(REFINER_DATA:%=%/labels.json) $(DATA)/refiner_val/labels.json
	$(BIN)/python -m uav_struct_env.training.train_refiner --data $(REFINER_DATA) \
		--out $(DETECTOR_RUN)/refiner $(REFINER_ARGS)

$(DETECTOR_RUN)/refiner_busy/refiner.onnx: $(DETECTOR_RUN)/keypoint/model.onnx \
		$(REFINER_DATA:%=%/labels.json) $(DATA)/refiner_busy/labels.json $(DATA)/refiner_val/labels.json
	$(BIN)/python -m uav_struct_env.training.train_refiner --data $(REFINER_DATA) $(DATA)/refiner_busy \
		--out $(DETECTOR_RUN)/refiner_busy $(REFINER_ARGS)

$(DETECTOR_RUN)/refiner.onnx: $(DETECTOR_RUN)/refiner/refiner.onnx $(DETECTOR_RUN)/refiner_busy/refiner.onnx
	$(BIN)/python -m uav_struct_env.training.ensemble $^ --out $@

# clean removes what the commands wrote and keeps the installed venv; distclean removes the venv too.
clean:
	rm -rf renders results site

distclean: clean
	rm -rf $(VENV)
