# The two commands of the README. Both are idempotent: they set up .venv/ when needed.
.PHONY: scan test setup lint

setup:
	@./scripts/setup_env.sh

scan: setup
	.venv/bin/scanner scan

# pytest exits 5 when no test was collected; that is not a failure of the install.
test: setup
	.venv/bin/python -m pytest; rc=$$?; if [ $$rc -eq 5 ]; then rc=0; fi; exit $$rc

lint: setup
	.venv/bin/ruff check .
