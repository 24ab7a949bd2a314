# The README's two commands. Each installs what is needed into ./.venv first.
.PHONY: app test install

install:
	bash scripts/install.sh

app: install
	.venv/bin/python -m app

# The suite on two pytest-xdist workers, whole test files each (their module fixtures are
# built once); tests/conftest.py gives each worker its share of the cores' threads.
# TEST_WORKERS=0 runs it in one process.
TEST_WORKERS ?= 2

test: install
	.venv/bin/python -m pytest -n $(TEST_WORKERS) --dist loadfile
