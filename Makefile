# The README's two commands. Each installs what is needed into ./.venv first.
.PHONY: app test install

install:
	bash scripts/install.sh

app: install
	.venv/bin/python -m app

# Two workers, a test file each at a time, longest files first (tests/conftest.py); `make test
# TEST_WORKERS=0` runs in one process.
TEST_WORKERS ?= 2

test: install
	.venv/bin/python -m pytest -n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder
