# The two commands of the README. Both are idempotent: they set up .venv/ when needed.
.PHONY: scan test setup lint lock

setup:
	@./scripts/setup_env.sh

scan: setup
	.venv/bin/scanner scan

# The set-up with --tests also installs chromium (as root, via apt) for the browser tests of
# model.html; `make scan` skips it. pytest exits 5 when no test was collected; that is not a
# failure of the install. One worker per core (one more was measured: 505 s against 508 s, no
# gain), a test file per worker (its module fixtures are built once; the scans several files
# read are built once per run, see tests/conftest.py), the longest files first (LONGEST_FIRST
# there); a worker that crashes ends the run as failed (a restarted worker once left the run
# waiting forever); the ten slowest tests are listed at the end, so that a test that got slower
# shows.
test:
	@./scripts/setup_env.sh --tests
	.venv/bin/python -m pytest -n auto --dist loadfile --no-loadscope-reorder --max-worker-restart=0 --durations=10; rc=$$?; if [ $$rc -eq 5 ]; then rc=0; fi; exit $$rc

lint: setup
	.venv/bin/ruff check .

# Re-resolve the newest versions within pyproject.toml's ranges into requirements.lock (with hashes).
lock: setup
	.venv/bin/uv pip compile pyproject.toml --extra dev --generate-hashes --quiet \
		--python-version 3.11 --python-platform x86_64-manylinux_2_35 -o requirements.lock
