"""scripts/why_height_hardness.py: the check behind docs/geometry.md's "Does the height map
carry hardness?", run small."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

from ratouch.paths import geometry_calibration

REPO = Path(__file__).resolve().parents[1]


def _script(name: str):
    spec = importlib.util.spec_from_file_location(name, REPO / "scripts" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.skipif(not geometry_calibration().is_file(), reason="no geometry calibration")
def test_height_hardness_check_reports_every_family(capsys):
    script = _script("why_height_hardness")
    script.main(["4", "1"])
    out = json.loads(capsys.readouterr().out)
    assert set(out) == {"digit", "gelsight", "mini"}
    for r in out.values():
        assert r["renders"] == 4 * len(script.KINDS)
        assert 0 < r["soft_share"] < 1 and 0.5 <= r["majority_accuracy"] <= 1
        assert 0 <= r["height_map_accuracy"] <= 1
