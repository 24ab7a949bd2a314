"""The house tools, run as CI runs them: lint (ruff), the layers contract (import-linter) and
the library's and the app's types (mypy). Each reads its configuration from pyproject.toml; a finding fails
the test with the tool's own report.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _run(*command: str, timeout: float) -> subprocess.CompletedProcess[str]:
    try:
        return subprocess.run(command, cwd=ROOT, capture_output=True, text=True,
                              timeout=timeout)
    except subprocess.TimeoutExpired:
        pytest.fail(f"{' '.join(command)} ran over {timeout:.0f} s", pytrace=False)


def _check(run: subprocess.CompletedProcess[str]) -> None:
    if run.returncode != 0:
        pytest.fail(f"{' '.join(run.args)} exited {run.returncode}:\n{run.stdout}\n{run.stderr}",
                    pytrace=False)


def test_ruff_finds_nothing():
    _check(_run(sys.executable, "-m", "ruff", "check", "ratouch", "app", "scripts", "tests",
                timeout=120))


def test_imports_keep_the_layers():
    """`[tool.importlinter]`: imports point down the layers of docs/architecture.md."""
    lint_imports = Path(sys.executable).with_name("lint-imports")
    _check(_run(str(lint_imports), "--no-cache", timeout=120))


@pytest.mark.slow
def test_mypy_finds_no_type_errors():
    """`[tool.mypy]` checks the library and the app: about a minute and a half from a fresh
    clone, a second or two on its cache (.mypy_cache) afterwards."""
    _check(_run(sys.executable, "-m", "mypy", timeout=600))
