"""The world's probe: it needs both senses, and the designed ambiguity shows."""

from __future__ import annotations

import json

import numpy as np
import pytest

from ratouch.cli import main


def test_probe_json_small(capsys):
    assert main(["world", "probe", "--n-train", "96", "--n-test", "48", "--workers", "1",
                 "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    for k in ("visual", "tactile", "both"):
        assert 0.0 <= r[k] <= 1.0
    assert set(r["confusion"]) == {"look", "feel"}


@pytest.mark.slow
def test_probe_needs_both_senses_and_shows_designed_ambiguity(capsys):
    assert main(["world", "probe", "--n-train", "1600", "--n-test", "500", "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert r["both"] > max(r["visual"], r["tactile"]) + 0.08
    assert min(r["visual"], r["tactile"]) > 5 * r["chance"]
    look, feel = r["confusion"]["look"], r["confusion"]["feel"]
    # vision mixes up the look-alikes, touch mixes up the feel-alikes, not the other way round
    assert np.mean(list(look["visual"].values())) > np.mean(list(look["tactile"].values())) + 0.08
    assert np.mean(list(feel["tactile"].values())) > np.mean(list(feel["visual"].values())) + 0.2
