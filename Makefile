# pseudostep: `make demo` runs the whole job on the bundled default profile, `make test` the tests.
# Both create the virtual environment .venv from nothing (Python 3.11 and pip are all they need).
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-stamp
OUT ?= demo-output
# off-screen display and silent audio for everything run from here
export SDL_VIDEODRIVER ?= dummy
export SDL_AUDIODRIVER ?= dummy
export MPLBACKEND ?= Agg

.PHONY: demo test benchmarks clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/python -m campaign demo --out $(OUT)

test: $(STAMP)
	$(BIN)/python -m pytest -q -n 2 tests

# `make benchmarks`: every script in benchmarks/ at a reduced size (15-16 min on an idle 2-core machine; the
# measured list is in docs/benchmarks.md). Run alone, each script keeps its full-size default;
# `make benchmarks BENCH_FULL=1` runs them all at full size (about 2 h), `BENCHES="benchmarks/x.py ..."`
# a selection (benchmarks/_*.py are helpers, not benchmarks; `python benchmarks/x.py --help` lists a
# script's options). Each script's output folder under benchmarks/output/ is removed first, so
# resumable stores (filter_error, frequency_fit, campaign) are recomputed, not resumed.
BENCHES ?= $(sort $(filter-out benchmarks/_%,$(wildcard benchmarks/*.py)))
BENCH_ARGS_campaign := 100
BENCH_ARGS_compat := 4
BENCH_ARGS_demo_under_load := --estimate
BENCH_ARGS_filter_error := --n 3 --baselines 2
BENCH_ARGS_filter_error_nonlinear := 10
BENCH_ARGS_filter_error_starts := 5
BENCH_ARGS_frequency := --quick
BENCH_ARGS_frequency_fit := --realisations 10
BENCH_ARGS_ml_long_record := 0.25
BENCH_ARGS_multisine_design := --mc 10 --quick-design --cases s61_hover_8state
BENCH_ARGS_paper_s61 := --seeds 1
BENCH_ARGS_prior := 20
BENCH_ARGS_refine_blind := --cases two_effects,small_Xde,null_s61
BENCH_ARGS_refine_coloured := 10
BENCH_ARGS_refine_fr := 6
BENCH_ARGS_refine_speed := 1
BENCH_ARGS_signal_design := --mc 20 --seeds 1 --durations 7
BENCH_ARGS_structure := 2
# always: filter_error's resumable store goes to benchmarks/output/, never the working directory
BENCH_ALWAYS_filter_error := --save benchmarks/output/filter_error/filter_error_turbulence.jsonl
bench_args = $(if $(BENCH_FULL),,$(BENCH_ARGS_$(1))) $(BENCH_ALWAYS_$(1))

benchmarks: $(STAMP)
	@before=$$(git status --porcelain 2>/dev/null); start=$$(date +%s); \
	$(foreach b,$(BENCHES),$(call bench_one,$(b),$(basename $(notdir $(b))))) \
	after=$$(git status --porcelain 2>/dev/null); \
	if [ "$$before" != "$$after" ]; then echo "make benchmarks: FAILED, tracked or untracked files changed:"; \
	  echo "before:"; echo "$$before"; echo "after:"; echo "$$after"; exit 1; fi; \
	printf "make benchmarks: time per script$$times\n"; \
	echo "make benchmarks: total $$(( $$(date +%s) - start )) s$(if $(BENCH_FULL), (full size),)"

# one script: clear its output folder, run it, stop everything if it fails, print its time
bench_one = rm -rf benchmarks/output/$(2); mkdir -p benchmarks/output/$(2); t=$$(date +%s); \
	echo "== $(1) $(strip $(call bench_args,$(2)))"; \
	$(BIN)/python $(1) $(call bench_args,$(2)) || { echo "make benchmarks: FAILED in $(1)"; exit 1; }; \
	echo "== $(1): $$(( $$(date +%s) - t )) s"; times="$$times\n  $(1): $$(( $$(date +%s) - t )) s";

clean:
	rm -rf $(VENV) $(OUT) .pytest_cache
