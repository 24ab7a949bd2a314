# The README's two commands. Each installs what is needed into ./.venv first.
.PHONY: app test install

install:
	bash scripts/install.sh

app: install
	.venv/bin/python -m app

test: install
	.venv/bin/python -m pytest
