"""The RA-Touch query pipeline (shipped weights) and `ratouch query`, as a user meets them."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from ratouch.errors import DataError


def test_query_returns_every_documented_field(pipeline, world):
    s = world.sample("test", 120)
    r = pipeline.query(s.visual, s.tactile, box=s.box, k=5, label=s.caption)
    assert set(r["neighbours"]) == {"image", "tactile", "joint"}
    for mode, items in r["neighbours"].items():
        assert len(items) == 5
        assert {"id", "score", "class_name", "caption"} <= set(items[0])
        assert [i["score"] for i in items] == sorted((i["score"] for i in items), reverse=True)
    for system in ("ra_touch", "baseline"):
        words = [w for w in r["description"][system].split(",") if w.strip()]
        assert 1 <= len(words) <= 5
    roles = {p["role"] for p in r["pca"]["points"]}
    assert {"query_image", "query_tactile", "query_joint", "neighbour_joint",
            "ground_truth"} <= roles
    assert "total" in r["timings_ms"] and r["timings_ms"]["total"] > 0
    assert r["warnings"] == []
    json.dumps(r)  # JSON-ready


def test_missing_tactile_falls_back_to_image_only(pipeline, world):
    s = world.sample("test", 130)
    r = pipeline.query(s.visual, None, box=s.box)
    assert set(r["neighbours"]) == {"image"}
    assert any("tactile" in w for w in r["warnings"])


def test_default_box_and_odd_images(pipeline, world):
    s = world.sample("test", 140)
    rgba = Image.fromarray(s.visual).convert("RGBA")
    gray16 = Image.fromarray((s.tactile.mean(2) * 257).astype(np.uint16))
    r = pipeline.query(rgba, gray16)
    assert any("box" in w for w in r["warnings"])
    assert len(r["neighbours"]["joint"]) == 5


@pytest.mark.parametrize("box", [(10, 10, 10, 40), (50, 50, 20, 20), (500, 500, 600, 600)])
def test_bad_boxes_get_a_clear_message(pipeline, world, box):
    s = world.sample("test", 150)
    with pytest.raises(DataError, match="box"):
        pipeline.query(s.visual, s.tactile, box=box)


def test_cli_query_json(tmp_path, shipped_corpus, world, capsys):
    from ratouch.cli import main

    s = world.sample("test", 160)
    Image.fromarray(s.visual).save(tmp_path / "v.png")
    Image.fromarray(s.tactile).save(tmp_path / "t.png")
    code = main(["query", "--vision", str(tmp_path / "v.png"), "--tactile", str(tmp_path / "t.png"),
                 "--box", ",".join(map(str, s.box)), "--k", "3", "--corpus", str(shipped_corpus),
                 "--json"])
    assert code == 0
    r = json.loads(capsys.readouterr().out)
    assert len(r["neighbours"]["joint"]) == 3
    assert set(r["description"]) == {"ra_touch", "baseline"}
    (tmp_path / "bad.png").write_text("not an image")
    assert main(["query", "--vision", str(tmp_path / "bad.png"), "--corpus",
                 str(shipped_corpus)]) == 2
