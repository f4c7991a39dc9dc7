# Every target creates .venv when missing and installs the project with its test extras.
# Idempotent: the install step re-runs only when pyproject.toml changes.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test bench lint clean chromium docs

# The installer is uv (from PyPI, into the venv: it resolves, downloads and installs in
# parallel, a few seconds where pip takes half a minute); where uv cannot be had or fails,
# pip does it all as before.  The venv starts without pip (ensurepip's install of it costs
# 2-3 s): the interpreter's own pip puts uv into it (`pip --python`), else the venv's
# ensurepip gives it a pip first; uv then installs pip with the project (the wheel test's
# fresh environment uses it).  The bytecode is compiled at install, as pip does (a process
# started with PYTHONDONTWRITEBYTECODE would otherwise compile every module it imports, every
# time), except the libraries' own test suites, which nothing here imports: one compileall
# per 500 files, as many at once as there are cores (`compileall -j0` hands the ~5,800
# files to its workers one by one, and that traffic cost as much CPU as the compiling)
$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv --without-pip $(VENV)
	@if { test -x $(BIN)/uv || \
	      $(PY) -m pip --python $(BIN)/python install --quiet --disable-pip-version-check uv >/dev/null 2>&1 || \
	      { $(BIN)/python -m ensurepip --default-pip >/dev/null 2>&1 && \
	        $(BIN)/python -m pip install --quiet --disable-pip-version-check uv >/dev/null 2>&1; }; } && \
	  $(BIN)/uv pip install --quiet --python $(BIN)/python -e '.[test]' pip; then \
	  echo "installed with uv; compiling the bytecode"; \
	  find $(VENV)/lib -name '*.py' ! -path '*/site-packages/*/tests/*' -print0 | \
	    xargs -0 -n 500 -P "$$(nproc 2>/dev/null || echo 2)" \
	    $(BIN)/python -m compileall -q >/dev/null || true; \
	else \
	  echo "uv could not be had or failed: installing with pip"; \
	  { $(BIN)/python -m pip --version >/dev/null 2>&1 || $(BIN)/python -m ensurepip --default-pip >/dev/null 2>&1 || \
	    { echo "cannot install: $(PY) has neither pip nor ensurepip (Debian/Ubuntu: apt install python3-venv)" >&2; exit 1; }; } && \
	  $(BIN)/python -m pip install --quiet --upgrade pip && \
	  $(BIN)/python -m pip install --quiet -e '.[test]'; \
	fi
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/pmalab demo --out demo-output --force

# basedpyright (~25 CPU-s, mostly one core) runs beside the suite at the lowest priority
# (nice 19): it takes only what the suite leaves idle (tests waiting on real-time recordings,
# emulators, kill tests) instead of a third of the cores while the suite is busy; its report
# follows the tests' (with how long the tests waited for it: 0 s when the idle time sufficed)
# and either failing fails the target
test: $(STAMP) chromium
	$(BIN)/ruff check pmalab tests bench docs
	$(BIN)/ruff format --check pmalab
	$(BIN)/lint-imports
	@# the project's own bytecode, once (as the install step does for the libraries): with
	@# PYTHONDONTWRITEBYTECODE set, every process the suite starts (commands in
	@# subprocesses, the docs build's, pool workers) would compile every pmalab module it imports
	$(BIN)/python -m compileall -q -j0 pmalab tests bench docs >/dev/null
	@echo "pytest: the whole suite in parallel (pytest-xdist, one worker per core, a test file per worker), basedpyright beside it: ~5-6 min on 2 idle cores (longer under load); the 10 slowest tests are listed at the end"
	@nice -n 19 $(BIN)/basedpyright > $(VENV)/basedpyright.log 2>&1 & typing=$$!; \
	trap 'kill $$typing 2>/dev/null' INT TERM; \
	$(BIN)/python -m pytest -n auto --dist loadfile --no-loadscope-reorder -q --durations=10; tests=$$?; \
	tested=$$(date +%s); wait $$typing; typed=$$?; late=$$(( $$(date +%s) - tested )); \
	echo "basedpyright (at nice 19 in the time the suite leaves idle; the tests then waited $$late s for it):"; \
	cat $(VENV)/basedpyright.log; \
	if [ $$tests -ne 0 ]; then exit $$tests; fi; exit $$typed

# headless Chromium for the live-view browser test (Debian's package); never fails the
# build: without apt (or root) the test is skipped with a message
chromium:
	@command -v chromium >/dev/null 2>&1 || command -v chromium-browser >/dev/null 2>&1 || \
	  (apt-get install -y -q chromium >/dev/null 2>&1 || \
	   (apt-get update -q >/dev/null 2>&1 && apt-get install -y -q chromium >/dev/null 2>&1)) || \
	  echo "note: could not install chromium (apt-get unavailable or not root): the live-view browser test will be skipped"

bench: $(STAMP)
	$(BIN)/python -m bench

# the documentation site, strictly built (a broken link or cross-reference fails); the
# build runs every tutorial page's commands, the notebook and docs/make_figures.py and shows
# their output and figures (cached by code hash in ~/.cache/pmalab/docs; nothing is written
# into the tree); the result is in site/
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict

lint: $(STAMP)
	$(BIN)/ruff check pmalab tests bench docs
	$(BIN)/ruff format --check pmalab
	$(BIN)/lint-imports
	$(BIN)/basedpyright

clean:
	rm -rf $(VENV) demo-output .pytest_cache site
