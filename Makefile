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

benchmarks: $(STAMP)
	@start=$$(date +%s); for b in benchmarks/*.py; do t=$$(date +%s); echo "== $$b"; \
	  $(BIN)/python $$b || exit 1; echo "== $$b: $$(( $$(date +%s) - t )) s"; done; \
	echo "make benchmarks: total $$(( $$(date +%s) - start )) s"

clean:
	rm -rf $(VENV) $(OUT) .pytest_cache
