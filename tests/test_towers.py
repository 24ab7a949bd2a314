"""`ratouch bench towers`: the vision towers' speed against accuracy on validation renders, on a
tiny run (behaviour and shape, not the figures: those come from the full run)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from ratouch.bench.towers import (
    TOLERANCE,
    bench_towers,
    choose,
    format_towers,
    precision_at_k,
    tower_chart,
    write_towers,
)
from ratouch.errors import ConfigError, DataNotFoundError, ServiceError

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def result():
    try:
        from ratouch.encoders.prior import load_prior

        load_prior("lite0")
    except DataNotFoundError as e:
        pytest.skip(f"lite0 prior not installed: {e}")
    return bench_towers(n=40, sizes=(64, 96), towers=("cnn", "lite0"), encoder="debug",
                        cnn_weights=None, gallery=168, latency_reps=5, batch=8, threads=1)


def test_documented_keys_and_ranges(result):
    assert {"points", "skipped", "rule", "tolerance", "best", "choice", "chance",
            "settings"} <= set(result)
    assert result["skipped"] == []
    labels = [p["label"] for p in result["points"]]
    assert labels == ["cnn@32 (random weights)", "lite0@64", "lite0@96"]
    for p in result["points"]:
        assert {"tower", "size", "dim", "probe_accuracy", "probe_folds", "precision_at_5",
                "p50_ms", "p95_ms", "p50_ms_1_thread", "throughput_per_s"} <= set(p)
        assert 0.0 <= p["probe_accuracy"] <= 1.0 and len(p["probe_folds"]) == 2
        assert 0.0 <= p["precision_at_5"] <= 1.0
        assert p["p50_ms"] > 0 and p["throughput_per_s"] > 0
    assert result["points"][1]["dim"] == 1280
    assert "within 0.02 of the best" in result["rule"]
    assert result["choice"]["label"] in labels
    s = result["settings"]
    assert s["renders"].startswith("train[1200000:1200040]")  # validation renders, not test
    json.dumps(result)  # serialisable as is
    assert "chosen:" in format_towers(result)


def test_choice_follows_the_rule():
    pts = [{"label": "a", "probe_accuracy": 0.80, "p50_ms": 50.0},
           {"label": "b", "probe_accuracy": 0.79, "p50_ms": 10.0},
           {"label": "c", "probe_accuracy": 0.70, "p50_ms": 1.0}]
    assert choose(pts)["label"] == "b"
    assert choose(pts, tolerance=0.0)["label"] == "a"
    assert choose([]) is None
    assert TOLERANCE == 0.02


def test_precision_at_k():
    q = np.eye(2, dtype=np.float32)
    g = np.array([[1, 0], [0.9, 0.1], [0, 1]], np.float32)
    assert precision_at_k(q, ["x", "y"], g, ["x", "x", "y"], k=1) == 1.0
    assert precision_at_k(q, ["x", "y"], g, ["x", "x", "y"], k=2) == 0.75


def test_unknown_tower_and_missing_cnn_weights():
    with pytest.raises(ConfigError, match="unknown tower"):
        bench_towers(n=8, towers=("vit",))
    r = bench_towers(n=8, towers=("cnn",), encoder="debug", gallery=168, latency_reps=2,
                     batch=4, threads=1)   # `debug` ships no weights: a clear skip
    assert r["points"] == [] and r["choice"] is None
    assert r["skipped"][0]["tower"] == "cnn" and "debug" in r["skipped"][0]["reason"]


def test_chart_png(result, tmp_path):
    try:
        data = tower_chart(result)
    except ServiceError as e:
        out = write_towers(result, tmp_path / "towers.png")   # falls back to the HTML figure
        assert "html" in out and "note" in out and json.loads(
            (tmp_path / "towers.data.json").read_text())["rule"] == result["rule"]
        pytest.skip(f"no PNG exporter here (kaleido needs Chrome/Chromium): {e}")
    assert data.startswith(PNG_SIGNATURE)


def test_cli_bench_towers(tmp_path, capsys):
    from ratouch.cli import main

    try:
        from ratouch.encoders.prior import load_prior

        load_prior("lite0")
    except DataNotFoundError as e:
        pytest.skip(f"lite0 prior not installed: {e}")
    out = tmp_path / "figs" / "towers.png"
    assert main(["bench", "towers", "--n", "40", "--towers", "lite0", "--sizes", "64",
                 "--gallery", "168", "--reps", "3", "--threads", "1", "--out", str(out),
                 "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert [p["label"] for p in r["points"]] == ["lite0@64"]
    assert r["choice"]["label"] == "lite0@64" and r["settings"]["n"] == 40
    assert (tmp_path / "figs" / "towers.data.json").is_file()
    assert ("png" in r["files"] and out.read_bytes().startswith(PNG_SIGNATURE)) or (
        "html" in r["files"] and (tmp_path / "figs" / "towers.html").is_file())


def test_cli_bench_towers_bad_tower(capsys):
    from ratouch.cli import main

    assert main(["bench", "towers", "--towers", "lite0,vit"]) == 2
    assert "unknown tower" in capsys.readouterr().err
