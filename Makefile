# tacrom: `make demo` and `make test` do all set-up on a fresh machine (Rust and python3).
SHELL := /bin/bash
VENV := .venv
PY := $(VENV)/bin/python
PIP := $(VENV)/bin/pip
LIB := target/release/libtacrom.so
PKG_LIB := python/tacrom/_lib/libtacrom.so
CARGO ?= cargo

.PHONY: all venv build wheel demo test test-rust test-python bench bench-report bench-quick bench-micro bench-mpm stability fuzz soak train-env taxim-env real-data sensor-gelsight-mini real-check real-table gen-data gen-data-linear gen-data-linear-material gen-data-linear-shapes gen-data-linear-small05 gen-data-linear-049 gen-data-family gen-data-family-shard gen-data-family-validation train-family train-family-ablations eval-family-ablations ship-family force-factor-linear train-linear train-linear-narrow train-linear-seeds gen-data-fine reference-study gen-data-pressure train-pressure gen-data-material train train-material eval-rom eval-rom-material force-factor test-train clean

all: build

# Python environment with the pinned MuJoCo and ONNX Runtime wheels.
$(VENV)/.installed: python/requirements.txt
	python3 -m venv $(VENV)
	$(PIP) install -q -r python/requirements.txt
	touch $@

venv: $(VENV)/.installed

# The plugin library, copied into the Python package, which is installed (editable) so
# that `import mujoco` registers the plugin through its entry point.
$(VENV)/.tacrom-installed: $(VENV)/.installed python/pyproject.toml
	$(PIP) install -q --no-build-isolation --no-deps -e python
	touch $@

# The library is replaced only when it changed, and atomically (written beside, then
# renamed): a running Python process keeps its mapping of the old file, which `cp` over it
# would truncate (SIGBUS inside mj_forward).
build: venv
	$(CARGO) build --release
	mkdir -p $(dir $(PKG_LIB))
	cmp -s $(LIB) $(PKG_LIB) || { cp $(LIB) $(PKG_LIB).tmp.$$$$ && mv -f $(PKG_LIB).tmp.$$$$ $(PKG_LIB); }
	$(MAKE) --no-print-directory $(VENV)/.tacrom-installed

# dist/tacrom-*.whl: the package with the plugin library, the rom-default model and the
# environments' scenes (python/build_wheel.py; setuptools, no network).
wheel: build
	$(PY) python/build_wheel.py --out dist

demo: build
	$(PY) examples/demo.py --out out/demo --physics rigid coarse rom rom-default
	$(PY) examples/gripper.py --out out/gripper --physics rigid --resolution 64 48
	$(PY) examples/rest.py --physics coarse --seconds 0.3

# The tests keep the gel cache (the linear solver's surface compliance, docs/solvers.md)
# in the build folder, not in the user's.
test-rust test-python bench-quick: export TACROM_CACHE := $(CURDIR)/target/tacrom-cache

test-rust: venv
	$(CARGO) test --release

# The Python tests run one worker per core (pytest-xdist), each test file on one worker so
# that its module fixtures are built once; the slowest tests are listed at the end.
test-python: build
	$(PY) -m pytest tests/python -q -n auto --dist loadfile --durations=15

test: build test-rust test-python bench-quick real-check

# The press benchmark (error against run time of every mode; docs/benchmarks.md).
bench: build
	$(CARGO) run --release --bin tacrom -- mpm --fine
	$(CARGO) run --release --bin tacrom -- bench --full

# The committed full-profile report (docs/benchmark/report.md) and its accuracy rows
# (benchmarks/full-baseline.json): every pattern at the centre position against the 0.5 mm
# reference (docs/results.md: why not the 0.3 mm one and the 3 x 3 grid yet).
BENCH_REPORT_MODES = rigid coarse rom coarse-linear rom-linear coarse-tol1e-3 coarse-tol1e-2 \
	rom-tol1e-3 rom-tol1e-2 rom-norefine rom-latent16 rom-no-multiscale \
	coarse-newton:physics=coarse,solver=newton
bench-report: build
	$(CARGO) run --release --bin tacrom -- bench --full --grid 1 --reference-dx 0.5 \
		$(addprefix --mode ,$(BENCH_REPORT_MODES)) --out docs/benchmark --panels 2 \
		--write-baseline benchmarks/full-baseline.json --quiet

# The quick benchmark, checked against its committed accuracy baseline (bench/check.rs):
# rom < coarse < rigid in depth error, no mode's error drifting up, and each mode's error
# relative to coarse's within what the committed full profile measured.
bench-quick: venv
	$(CARGO) run --release --bin tacrom -- bench --quick --check benchmarks/quick-baseline.json \
		--check-full benchmarks/full-baseline.json

# Micro-benchmarks of one sensor evaluation per mode and indenter.
bench-micro: build
	$(CARGO) bench --bench sensor

# Hertz validation and solver cost per grid spacing, without the fine spacing.
bench-mpm: build
	$(CARGO) run --release --bin tacrom -- mpm

# Coverage-guided fuzzing of the parsers and loaders (tacrom::fuzzing; libFuzzer through
# cargo-fuzz, which needs the nightly toolchain and `cargo install cargo-fuzz`; not part of
# `make test`, which replays the committed corpora through the same targets). Each target
# runs FUZZ_RUNS inputs from fuzz/corpus/TARGET, keeping what it finds in fuzz/work/TARGET
# and a crashing input in fuzz/artifacts/TARGET.
FUZZ_RUNS ?= 1000000
FUZZ_TARGETS ?= config mesh optics manifest graph state presses
fuzz:
	cd fuzz && for t in $(FUZZ_TARGETS); do mkdir -p work/$$t && \
	  cargo +nightly fuzz run -O $$t work/$$t corpus/$$t -- -runs=$(FUZZ_RUNS) -max_len=16384 \
	  -timeout=10 -rss_limit_mb=3000 -print_final_stats=1 || exit 1; done

# Soak runs in real MuJoCo (not part of `make test`): SOAK_CYCLES load / evaluate / copy /
# state / reset / free cycles and SOAK_EVALUATIONS random-walk evaluations per mode, with
# the memory growth of each second half (examples/soak.py; docs/benchmarks.md); and
# SOAK_GRASP steps of the coupled gripper's grasp cycle and SOAK_SHAKE steps of it shaken at
# random (0: none; about 200 episodes, 20000 steps, measure the memory growth past the
# warm-up).
SOAK_CYCLES ?= 1000
SOAK_EVALUATIONS ?= 100000
SOAK_MODES ?= rigid coarse coarse-linear rom rom-default
SOAK_GRASP ?= 0
SOAK_SHAKE ?= 0
soak: build
	$(PY) examples/soak.py --modes $(SOAK_MODES) --cycles $(SOAK_CYCLES) --evaluations $(SOAK_EVALUATIONS) \
	  --grasp $(SOAK_GRASP) --shake $(SOAK_SHAKE)

# The stability suite's table.
stability: venv
	$(CARGO) run --release --bin tacrom -- stability

clean:
	rm -rf target out dist $(VENV) python/tacrom/_lib python/*.egg-info

# --- Reduced-order model: data, training, export (PyTorch lives in its own .venv-train;
# installing it takes about 5 minutes and 5.5 GB, so it is not part of `make test`).
VENV_TRAIN := .venv-train
PY_TRAIN := $(VENV_TRAIN)/bin/python
ROM_DATA ?= data/rom-v2
ROM_SAMPLES ?= 300
ROM_SHARDS ?= 2
ROM_STEPS ?= 5000
# torch device of the training loop (cpu, cuda)
ROM_DEVICE ?= cpu
# The presses of ROM_DATA at the fine 0.3 mm spacing: by default only the held-out ones
# (validation); `make gen-data-fine ROM_FINE_FLAGS= ROM_FINE_SAMPLES=300` fills in the rest
# (training against the fine mode).
ROM_FINE_DATA ?= data/rom-v2-f0.3
ROM_FINE_SAMPLES ?= 120
ROM_FINE_FLAGS ?= --held-out-only

$(VENV_TRAIN)/.installed: training/requirements.txt
	python3 -m venv $(VENV_TRAIN)
	$(VENV_TRAIN)/bin/pip install -q -r training/requirements.txt
	touch $@

train-env: $(VENV_TRAIN)/.installed

# Paired coarse / reference presses, sharded (one shard per core) and resumable.
gen-data: build
	for k in $$(seq 0 $$(($(ROM_SHARDS)-1))); do \
	  target/release/tacrom gen-data --out $(ROM_DATA) --samples $(ROM_SAMPLES) --seed 1 \
	    --fine-dx 0.7 --fine-max-iterations 1000 --shard $$k/$(ROM_SHARDS) & \
	done; wait

# Trains and exports the shipped model and its two ablations into models/. The reference
# of ROM_REFERENCE (the same presses at the fine spacing) replaces ROM_DATA's wherever it
# holds the press, as for the shipped models; `make train ROM_REFERENCE=` trains against
# ROM_DATA's 0.7 mm reference alone.
ROM_REFERENCE ?= $(ROM_FINE_DATA)
TRAIN = PYTHONPATH=training $(PY_TRAIN) -m tacrom_rom.train --data $(ROM_DATA) --steps $(ROM_STEPS) \
	$(if $(ROM_REFERENCE),--reference $(ROM_REFERENCE))
train: train-env
	$(TRAIN) --out models/rom-default
	$(TRAIN) --out models/rom-latent16 --latent 16
	$(TRAIN) --out models/rom-no-multiscale --no-multiscale

# The model of the linear solver's coarse solve (`solver="linear"`, models/rom-linear): the
# presses of ROM_DATA with the linear coarse channel and those of ROM_SHAPES_DATA (blobs,
# stones; bricks held out), against the 0.7 mm reference (trained in 681 s on two threads); its
# force factor per Poisson's ratio from those presses and ROM_LINEAR_MAT_SAMPLES more whose
# Poisson's ratio and friction are drawn per press from ROM_POISSON and ROM_FRICTION
# (merged), and its decoder in 8 bits. `train-linear-seeds` trains, on the merged presses,
# three seeds of a model conditioned on the material, of each of its ablations, of one
# without the material inputs and of one conditioned on Poisson's ratio alone into
# out/models (docs/rom.md's seed table; 15 runs, each about 95 s on one GPU with
# ROM_DEVICE=cuda; measured, not shipped).
ROM_LINEAR_DATA ?= data/rom-linear
ROM_LINEAR_MAT_DATA ?= data/rom-linear-mat
ROM_LINEAR_MAT_SAMPLES ?= 400
ROM_LINEAR_MERGED := data/rom-linear-merged
gen-data-linear: build
	for k in $$(seq 0 $$(($(ROM_SHARDS)-1))); do \
	  target/release/tacrom gen-data --out $(ROM_LINEAR_DATA) --samples $(ROM_SAMPLES) --seed 1 \
	    --fine-dx 0.7 --fine-max-iterations 1000 --coarse-solver linear --shard $$k/$(ROM_SHARDS) & \
	done; wait
gen-data-linear-material: build
	for k in $$(seq 0 $$(($(ROM_SHARDS)-1))); do \
	  target/release/tacrom gen-data --out $(ROM_LINEAR_MAT_DATA) --samples $(ROM_LINEAR_MAT_SAMPLES) \
	    --seed 1 --fine-dx 0.7 --fine-max-iterations 1000 --coarse-solver linear \
	    --poisson $(ROM_POISSON) --friction $(ROM_FRICTION) --shard $$k/$(ROM_SHARDS) & \
	done; wait
# The held-out presses at Poisson's ratio 0.49, the top of the gel family, that extended the
# linear models' `materials` from 0.48 to 0.49 (61 presses, friction drawn from 0 to 1; about 10
# minutes on two shards; `tacrom eval-rom --data data/rom-linear-mat049 --models
# models/rom-linear,models/rom-linear-narrow`; docs/rom.md, "Poisson's ratio 0.49").
ROM_LINEAR_049_DATA ?= data/rom-linear-mat049
gen-data-linear-049: build
	for k in $$(seq 0 $$(($(ROM_SHARDS)-1))); do \
	  target/release/tacrom gen-data --out $(ROM_LINEAR_049_DATA) --samples 400 --seed 2 --held-out-only \
	    --fine-dx 0.7 --fine-max-iterations 1000 --coarse-solver linear \
	    --poisson 0.49 --friction $(ROM_FRICTION) --shard $$k/$(ROM_SHARDS) & \
	done; wait
# Presses over the gel family (issue 54: 12 to 40 mm a side, 1 to 6 mm thick, Poisson's ratio
# 0.3 to 0.49, friction 0 to 1, pressed anywhere, edges included), every indenter family
# with the blobs, stones and bricks, each indenter scaled by 0.5 to 2: `tacrom gen-data
# --gel-family` solves each in the model's units (the default gel's 4 mm thickness, sides
# in thicknesses, cut at 9) with the linear coarse gel at 1.4 mm and the relaxation at 0.5
# mm (T / 8, docs/rom.md's reference study) and writes the window of the model's lattice
# over the contact. Sharded (ROM_SHARDS, one per core) and resumable; about 10 s a press
# on one core. On a cluster the same command runs as an array, one shard per task:
#   sbatch --array=0-63 --wrap 'make gen-data-family-shard ROM_SHARD=$$SLURM_ARRAY_TASK_ID/64'
ROM_FAMILY_DATA ?= data/rom-family
ROM_FAMILY_SAMPLES ?= 1500
ROM_FAMILY_FAMILIES := sphere,cylinder,box,edge,bumps,ridges,heightfield,mesh,blob,stone,brick
GEN_FAMILY_FLAGS = --gel-family --families $(ROM_FAMILY_FAMILIES) --poisson 0.3,0.49 --friction 0,1 \
	--coarse-solver linear --fine-dx 0.5 --fine-max-iterations 3000
GEN_FAMILY = TACROM_CACHE=off target/release/tacrom gen-data $(GEN_FAMILY_FLAGS) --out $(ROM_FAMILY_DATA) \
	--samples $(ROM_FAMILY_SAMPLES) --seed 3
gen-data-family: build
	for k in $$(seq 0 $$(($(ROM_SHARDS)-1))); do \
	  $(GEN_FAMILY) --shard $$k/$(ROM_SHARDS) & \
	done; wait
gen-data-family-shard: build
	$(GEN_FAMILY) --shard $(ROM_SHARD)
# Validation sets of three named gels of the family, thin, default and thick (FOLDER:X,Y,T
# in mm): the held-out families' presses among ROM_FAMILY_VALIDATION_SAMPLES draws of
# another seed, every one on that gel (`--gel-size`), solved as above: the same 19 presses
# of six held-out families on each gel, about 15 minutes on two shards. The family model's
# `validation/` pairs come from them (`ship-family`), gated per gel by tests/rom.rs.
ROM_FAMILY_VALIDATION := data/rom-family-val-thin:18,14,1.5 data/rom-family-val-default:30,30,4 \
	data/rom-family-val-thick:40,30,6
ROM_FAMILY_VALIDATION_SAMPLES ?= 100
gen-data-family-validation: build
	for v in $(ROM_FAMILY_VALIDATION); do \
	  for k in $$(seq 0 $$(($(ROM_SHARDS)-1))); do \
	    TACROM_CACHE=off target/release/tacrom gen-data $(GEN_FAMILY_FLAGS) --out $${v%%:*} \
	      --samples $(ROM_FAMILY_VALIDATION_SAMPLES) --seed 4 --gel-size $${v#*:} --held-out-only \
	      --shard $$k/$(ROM_SHARDS) & \
	  done; wait; \
	done
# Models trained on the family's presses beside every default-gel press of the linear model
# (ROM_LINEAR_ALL: drawn materials, shapes and the default set, merged), conditioned on the
# material over the family's ranges, one per seed, into out/models (compared with `tacrom
# eval-rom`: docs/rom.md, "One model for the family"); models/rom-family was trained on the
# first 881 presses of ROM_FAMILY_DATA (its manifest's `data`).
ROM_LINEAR_ALL := data/rom-linear-all
ROM_FAMILY_MODEL ?= out/models/rom-family
$(ROM_LINEAR_ALL)/dataset.json:
	PYTHONPATH=training $(PY_TRAIN) -m tacrom_rom.merge $(ROM_LINEAR_ALL) $(ROM_LINEAR_MAT_DATA) $(ROM_SHAPES_DATA) $(ROM_LINEAR_DATA)
ROM_FAMILY_SEEDS ?= 0 1 2
TRAIN_FAMILY = PYTHONPATH=training $(PY_TRAIN) -m tacrom_rom.train --data $(ROM_FAMILY_DATA) \
	--also $(ROM_LINEAR_ALL) --steps $(ROM_STEPS) --device $(ROM_DEVICE) --threads 2 \
	--region-eps-mm 0.01 --region-grow 2 --lr-schedule cosine --no-refinement
train-family: train-env $(ROM_LINEAR_ALL)/dataset.json
	for s in $(ROM_FAMILY_SEEDS); do \
	  $(TRAIN_FAMILY) --seed $$s --out $(ROM_FAMILY_MODEL)-s$$s || exit 1; \
	done
# The paper's ablations on the family's data (docs/rom.md, "The paper's ablations on the
# family"): latent 16 and no multi-scale loss, three seeds each (about 8 minutes a run on two
# threads), beside train-family's seeds; eval-family-ablations scores all nine, and each of
# the recipe's seeds with the latent refinement on, on the held-out families, the three
# named gels and the default gel. The ablations were measured on the first 881 presses
# (ROM_FAMILY_DATA=data/rom-family-881: those presses' files linked into a folder of their
# own with the set's dataset.json).
train-family-ablations: train-env $(ROM_LINEAR_ALL)/dataset.json
	for s in $(ROM_FAMILY_SEEDS); do \
	  $(TRAIN_FAMILY) --seed $$s --latent 16 --out $(ROM_FAMILY_MODEL)-latent16-s$$s || exit 1; \
	  $(TRAIN_FAMILY) --seed $$s --no-multiscale --out $(ROM_FAMILY_MODEL)-no-multiscale-s$$s || exit 1; \
	done
comma := ,
space := $(empty) $(empty)
FAMILY_ABLATION_MODELS = $(subst $(space),$(comma),$(strip $(foreach a,- -latent16- -no-multiscale-,\
	$(foreach s,$(ROM_FAMILY_SEEDS),$(ROM_FAMILY_MODEL)$(a)s$(s)))))
eval-family-ablations: build
	for d in $(ROM_FAMILY_DATA) $(foreach v,$(ROM_FAMILY_VALIDATION),$(firstword $(subst :, ,$(v)))) $(ROM_LINEAR_ALL); do \
	  target/release/tacrom eval-rom --data $$d --models $(FAMILY_ABLATION_MODELS) --refined \
	    --out out/bench/eval-family-ablations-$$(basename $$d) || exit 1; \
	done
# models/rom-family: the seed ROM_FAMILY_SEED of train-family (the median of the three on
# the family's held-out presses: docs/rom.md), its validation pairs from the three named
# gels' sets (gen-data-family-validation), its decoder in 8 bits, its force factor per
# Poisson's ratio fitted to its own decoded volumes on the family's training presses.
ROM_FAMILY_SEED ?= 1
ship-family: build
	rm -rf models/rom-family && cp -r $(ROM_FAMILY_MODEL)-s$(ROM_FAMILY_SEED) models/rom-family
	PYTHONPATH=training $(PY_TRAIN) -m tacrom_rom.validate models/rom-family \
		$(foreach v,$(ROM_FAMILY_VALIDATION),$(firstword $(subst :, ,$(v))))
	PYTHONPATH=training $(PY_TRAIN) -m tacrom_rom.quantize models/rom-family
	target/release/tacrom eval-rom --data $(ROM_FAMILY_DATA) --all --models models/rom-family \
		--out out/force-factor/rom-family
	PYTHONPATH=training $(PY) -m tacrom_rom.force_factor $(ROM_FAMILY_DATA) models/rom-family \
		--decoded out/force-factor/rom-family/forces.csv
# Presses of shapes outside the default families (`blob`, `stone` and, held out, `brick`:
# `tacrom gen-data --families`), the same gel and solvers as ROM_LINEAR_DATA; about 8
# minutes on two shards. `docs/rom.md`, "Shapes outside the training families".
ROM_SHAPES_DATA ?= data/rom-linear-shapes
ROM_SHAPES_SAMPLES ?= 480
gen-data-linear-shapes: build
	for k in $$(seq 0 $$(($(ROM_SHARDS)-1))); do \
	  target/release/tacrom gen-data --out $(ROM_SHAPES_DATA) --samples $(ROM_SHAPES_SAMPLES) --seed 1 \
	    --fine-dx 0.7 --fine-max-iterations 1000 --coarse-solver linear --families blob,stone,brick \
	    --shard $$k/$(ROM_SHARDS) & \
	done; wait
$(ROM_LINEAR_MERGED)/dataset.json:
	PYTHONPATH=training $(PY_TRAIN) -m tacrom_rom.merge $(ROM_LINEAR_MERGED) $(ROM_LINEAR_MAT_DATA) $(ROM_LINEAR_DATA)
ROM_LINEAR_SHAPES_MERGED := data/rom-linear-shapes-merged
$(ROM_LINEAR_SHAPES_MERGED)/dataset.json:
	PYTHONPATH=training $(PY_TRAIN) -m tacrom_rom.merge $(ROM_LINEAR_SHAPES_MERGED) $(ROM_SHAPES_DATA) $(ROM_LINEAR_DATA)
train-linear: train-env $(ROM_LINEAR_MERGED)/dataset.json $(ROM_LINEAR_SHAPES_MERGED)/dataset.json
	PYTHONPATH=training $(PY_TRAIN) -m tacrom_rom.train --data $(ROM_LINEAR_SHAPES_MERGED) --steps $(ROM_STEPS) \
		--device $(ROM_DEVICE) --threads 2 --region-eps-mm 0.01 --region-grow 2 --out models/rom-linear
	PYTHONPATH=training $(PY_TRAIN) -m tacrom_rom.quantize models/rom-linear
	$(MAKE) force-factor-linear ROM_FORCE_MODEL=models/rom-linear
# The force factor per Poisson's ratio of a linear model, from its own decoded volumes on the
# training presses of ROM_LINEAR_MERGED (`tacrom eval-rom --all`, then `tacrom_rom.force_factor
# --decoded`; docs/rom.md, "The force factor from the decoded volume"). A minute.
ROM_FORCE_MODEL ?= models/rom-linear
force-factor-linear: build $(ROM_LINEAR_MERGED)/dataset.json
	target/release/tacrom eval-rom --data $(ROM_LINEAR_MERGED) --all --models $(ROM_FORCE_MODEL) \
		--out out/force-factor/$(notdir $(ROM_FORCE_MODEL))
	PYTHONPATH=training $(PY) -m tacrom_rom.force_factor $(ROM_LINEAR_MERGED) $(ROM_FORCE_MODEL) \
		--decoded out/force-factor/$(notdir $(ROM_FORCE_MODEL))/forces.csv
# The presses of small footprint among ROM_LINEAR_DATA's and ROM_SHAPES_DATA's (rigid
# penetration at 1 to 43 lattice points: `tacrom_rom.small`) solved again at 0.5 mm, where the
# 0.7 mm reference is furthest from converged (docs/rom.md, "A narrower decoder"), merged as
# the shapes data are: 253 presses, 14 minutes on two shards.
ROM_SMALL05_MERGED := data/rom-linear-shapes-small05-merged
gen-data-linear-small05: build train-env
	set -e; for v in "$(ROM_LINEAR_DATA):$(ROM_SAMPLES):" \
	    "$(ROM_SHAPES_DATA):$(ROM_SHAPES_SAMPLES):--families blob,stone,brick"; do \
	  src=$${v%%:*}; rest=$${v#*:}; n=$${rest%%:*}; flags=$${rest#*:}; \
	  idx=$$(PYTHONPATH=training $(PY_TRAIN) -m tacrom_rom.small $$src); \
	  for k in $$(seq 0 $$(($(ROM_SHARDS)-1))); do \
	    target/release/tacrom gen-data --out $$src-small05 --samples $$n --seed 1 --fine-dx 0.5 \
	      --fine-max-iterations 1000 --coarse-solver linear $$flags --indices $$idx --shard $$k/$(ROM_SHARDS) & \
	  done; wait; \
	done
	PYTHONPATH=training $(PY_TRAIN) -m tacrom_rom.merge $(ROM_SMALL05_MERGED) $(ROM_SHAPES_DATA)-small05 $(ROM_LINEAR_DATA)-small05
# models/rom-linear-narrow: the default model's encoder (made by train-linear above) and a
# decoder of ROM_LINEAR_DECODER widths trained alone on its latent codes against the 0.7 mm
# reference with the small-footprint presses' 0.5 mm one overlaid, run in float (docs/rom.md,
# "A narrower decoder"). Its held-out pairs are then the encoder's model's (the 0.7 mm
# reference, which tests/rom.rs gates); the manifest's `materials` come from `tacrom eval-rom`
# on ROM_LINEAR_MAT_DATA's held-out presses (docs/rom.md).
ROM_LINEAR_DECODER ?= 128,64,32
train-linear-narrow: train-env $(ROM_LINEAR_MERGED)/dataset.json $(ROM_LINEAR_SHAPES_MERGED)/dataset.json
	PYTHONPATH=training $(PY_TRAIN) -m tacrom_rom.train --data $(ROM_LINEAR_SHAPES_MERGED) --steps 20000 --lr 5e-4 \
		--reference $(ROM_SMALL05_MERGED) \
		--device $(ROM_DEVICE) --threads 2 --region-eps-mm 0.01 --region-grow 2 --no-refinement \
		--encoder-from models/rom-linear --decoder-hidden $(ROM_LINEAR_DECODER) --out models/rom-linear-narrow
	rm -f models/rom-linear-narrow/validation/* && cp models/rom-linear/validation/* models/rom-linear-narrow/validation/
	$(MAKE) force-factor-linear ROM_FORCE_MODEL=models/rom-linear-narrow
train-linear-seeds: train-env $(ROM_LINEAR_MERGED)/dataset.json
	for s in 0 1 2; do for v in "conditioned:" "latent16:--latent 16" "no-multiscale:--no-multiscale" \
	    "unconditioned:--no-conditioning" "poisson-only:--poisson-only"; do \
	  PYTHONPATH=training $(PY_TRAIN) -m tacrom_rom.train --data $(ROM_LINEAR_MERGED) --steps $(ROM_STEPS) \
	    --seed $$s --device $(ROM_DEVICE) --region-eps-mm 0.01 $${v#*:} --out out/models/rom-linear-$${v%%:*}-s$$s; \
	done; done

# The presses of ROM_DATA again, with the reference at the fine 0.3 mm spacing (each takes
# 10 s to 22 min on one core); resumable like gen-data.
gen-data-fine: build
	for k in $$(seq 0 $$(($(ROM_SHARDS)-1))); do \
	  target/release/tacrom gen-data --out $(ROM_FINE_DATA) --samples $(ROM_FINE_SAMPLES) --seed 1 \
	    --fine-dx 0.3 --fine-max-iterations 3000 $(ROM_FINE_FLAGS) --shard $$k/$(ROM_SHARDS) & \
	done; wait

# The reference study (docs/rom.md, "A reference for any gel"): 24 presses over the gel family,
# each by its finest solve and by every candidate, then the table against the finest. The
# finest solves take 0.5 to 36 min each on one core; resumable; REF_WORKERS processes share the
# tasks, heaviest first (on a machine of more cores, or one shard of a batch job each).
REF_STUDY ?= out/reference-study
REF_WORKERS ?= 2
reference-study: build
	mkdir -p $(REF_STUDY) && find $(REF_STUDY) -name '*.claim' -delete
	for k in $$(seq 1 $(REF_WORKERS)); do \
	  target/release/tacrom probe reference_study out=$(REF_STUDY) claim=1 & \
	done; wait
	find $(REF_STUDY) -name '*.claim' -delete
	target/release/tacrom probe reference_study out=$(REF_STUDY) report

# Presses of other gel materials: Poisson's ratio and friction drawn per press from ROM_POISSON
# and ROM_FRICTION (0.7 mm reference). The evidence for the shipped model's manifest `materials`
# (`make eval-rom-material`) and, merged with ROM_DATA, the training set of a model conditioned
# on the material (`make train-material`; trained, measured and not shipped: docs/rom.md, "Gel materials").
ROM_MAT_DATA ?= data/rom-mat
ROM_MAT_SAMPLES ?= 400
ROM_POISSON ?= 0.3,0.48
ROM_FRICTION ?= 0,1
gen-data-material: build
	for k in $$(seq 0 $$(($(ROM_SHARDS)-1))); do \
	  target/release/tacrom gen-data --out $(ROM_MAT_DATA) --samples $(ROM_MAT_SAMPLES) --seed 1 \
	    --fine-dx 0.7 --fine-max-iterations 1000 --poisson $(ROM_POISSON) --friction $(ROM_FRICTION) \
	    --shard $$k/$(ROM_SHARDS) & \
	done; wait

eval-rom-material: build
	target/release/tacrom eval-rom --data $(ROM_MAT_DATA) --out out/bench/eval-rom-material

train-material: train-env
	PYTHONPATH=training $(PY_TRAIN) -m tacrom_rom.merge data/rom-mat-merged $(ROM_MAT_DATA) $(ROM_DATA)
	for s in 0 1 2; do \
	  PYTHONPATH=training $(PY_TRAIN) -m tacrom_rom.train --data data/rom-mat-merged --steps $(ROM_STEPS) \
	    --seed $$s --device $(ROM_DEVICE) --out out/models/rom-material-s$$s; \
	done

# The shipped model's force factor (manifest `force`) from the forces of ROM_DATA's training
# presses (`tacrom gen-data` records them; the shipped factor came from data/rom-v2-force,
# ROM_DATA's presses written with forces: `make gen-data ROM_DATA=data/rom-v2-force`).
force-factor: venv
	PYTHONPATH=training $(PY) -m tacrom_rom.force_factor $(ROM_DATA) models/rom-default

# The contact pressure head of models/rom-default (`files.pressure`: rom's force and
# pressure from the fine level), trained on ROM_PRESSURE_DATA: ROM_DATA's presses again with
# the reference at 0.5 mm and both solves' pressure recorded (the reference 12 to 25 s a
# press on one core); the autoencoder stays as it is.
ROM_PRESSURE_DATA ?= data/rom-p0.5
ROM_PRESSURE_STEPS ?= 3000
gen-data-pressure: build
	for k in $$(seq 0 $$(($(ROM_SHARDS)-1))); do \
	  target/release/tacrom gen-data --out $(ROM_PRESSURE_DATA) --samples $(ROM_SAMPLES) --seed 1 \
	    --fine-dx 0.5 --fine-max-iterations 3000 --shard $$k/$(ROM_SHARDS) & \
	done; wait
train-pressure: train-env
	PYTHONPATH=training $(PY_TRAIN) -m tacrom_rom.pressure --data $(ROM_PRESSURE_DATA) \
		--model models/rom-default --steps $(ROM_PRESSURE_STEPS) --threads 2

# rigid, coarse, rom and its ablations against both references on the held-out families.
eval-rom: build
	target/release/tacrom eval-rom --data $(ROM_DATA) --out out/bench/eval-rom-f0.7
	target/release/tacrom eval-rom --data $(ROM_FINE_DATA) --compare $(ROM_DATA) --out out/bench/eval-rom-f0.3

# ONNX parity (ONNX Runtime against PyTorch), a tiny train-and-export run, and feature
# parity (the decoder's inputs from the Rust run time against the training code's, on
# presses written by `tacrom rom-features`).
test-train: train-env
	$(CARGO) build --release -p tacrom-tools --bin tacrom
	PYTHONPATH=training $(PY_TRAIN) -m pytest -q -p no:cacheprovider training/tests

# --- Real presses (realdata/README.md): Taxim, the baseline renderer of
# realdata/taxim_render.py, in its own .venv-taxim (JAX on the CPU; not part of `make test`).
VENV_TAXIM := .venv-taxim

$(VENV_TAXIM)/.installed: realdata/requirements-taxim.txt
	python3 -m venv $(VENV_TAXIM)
	$(VENV_TAXIM)/bin/pip install -q -r realdata/requirements-taxim.txt
	touch $@

taxim-env: $(VENV_TAXIM)/.installed

# The real GelSight Mini presses as a calibration folder (downloads the pinned taxim wheel
# once into target/real/cache; realdata/README.md).
REAL_MINI := target/real/gelsight-mini
CALIBRATE_MINI := --mirror --holdout 3 --detect --threshold 20

real-data: venv
	$(PY) realdata/gelsight_mini.py prepare $(REAL_MINI)

# The shipped preset sensors/gelsight-mini: optics and gel fitted to every press but every
# third (held out), docs/calibration.md. About 20 minutes on two threads. The shipped files
# were fitted with the depth search before it was bounded by the half-space's depth; run
# today, this lands on a thinner gel (1.11 mm) that rom on the file's linear solver refuses
# (docs/calibration.md, "The press depths").
sensor-gelsight-mini: real-data
	$(CARGO) run --release --bin tacrom -- calibrate $(REAL_MINI) $(CALIBRATE_MINI) --gel \
		--thickness 1,1.25,1.5 --poisson 0.3,0.43,0.48 --blur 0,0.05,0.1,0.15,0.2,0.3 \
		--threads 2 --out sensors/gelsight-mini/optics.json
	cp $(REAL_MINI)/LICENSE-taxim sensors/gelsight-mini/LICENSE-taxim

# The held-out real presses against the preset (and the background, rigid, the default
# gel), checked against the committed table: fails on a regression of more than 0.005 in
# MAE or SSIM.
real-check: real-data
	$(CARGO) run --release --bin tacrom -- compare $(REAL_MINI) $(CALIBRATE_MINI) \
		--sensor gelsight-mini --baseline sensors/gelsight-mini/real-table.json

# Rewrites that table and the figure docs/real-mini.png, with Taxim's images when they
# were rendered (realdata/README.md: at the same centres and fitted depths).
real-table: real-data
	$(CARGO) run --release --bin tacrom -- compare $(REAL_MINI) $(CALIBRATE_MINI) \
		--sensor gelsight-mini --with-defaults --json sensors/gelsight-mini/real-table.json \
		--figure docs/real-mini.png \
		$$(test -d target/real/taxim-fit && echo --row taxim=@target/real/taxim-fit) \
		$$(test -d target/real/taxim-fit-shadow && echo --row taxim-shadow=@target/real/taxim-fit-shadow)
