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


# --- retrieval a user can take apart: attention, regenerate with other neighbours ------------

def test_query_reports_the_integrators_attention(pipeline, world):
    s = world.sample("test", 170)
    r = pipeline.query(s.visual, s.tactile, box=s.box, k=4)
    for path in ("image", "text"):
        w = r["attention"][path]
        assert len(w) == 4 and all(x >= 0 for x in w)
        assert sum(w) == pytest.approx(1.0, abs=1e-3)
    assert pipeline.query(s.visual, None, box=s.box)["attention"] == {}


def test_regenerate_with_pinned_dropped_and_swapped_neighbours(pipeline, world):
    from ratouch.errors import ConfigError

    s, other = world.sample("test", 180), world.sample("test", 30)
    r = pipeline.query(s.visual, s.tactile, box=s.box, k=5)
    ids = [n["id"] for n in r["neighbours"]["joint"]]
    same = pipeline.regenerate(s.visual, s.tactile, ids, box=s.box)
    assert same["description"]["ra_touch"] == r["description"]["ra_touch"]
    assert same["attention"] == r["attention"]
    assert [n["id"] for n in same["neighbours"]] == ids
    assert [n["score"] for n in same["neighbours"]] == pytest.approx(
        [n["score"] for n in r["neighbours"]["joint"]], abs=2e-4)
    kept = pipeline.regenerate(s.visual, s.tactile, ids[:2], box=s.box)
    assert len(kept["attention"]["text"]) == 2
    assert sum(kept["attention"]["image"]) == pytest.approx(1.0, abs=1e-3)
    swapped_ids = [n["id"] for n in pipeline.query(other.visual, other.tactile,
                                                   box=other.box)["neighbours"]["joint"]]
    swapped = pipeline.regenerate(s.visual, s.tactile, swapped_ids, box=s.box)
    assert [n["id"] for n in swapped["neighbours"]] == swapped_ids
    # no neighbours at all: the integrator adds nothing, so p' is the baseline prompt
    assert pipeline.regenerate(s.visual, s.tactile, [], box=s.box)["attention"] == {}
    for bad in ([len(pipeline.corpus)], [-1], [ids[0], ids[0]], ["3"]):
        with pytest.raises(ConfigError, match="neighbour ids"):
            pipeline.regenerate(s.visual, s.tactile, bad, box=s.box)
    with pytest.raises(ConfigError, match="tactile"):
        pipeline.regenerate(s.visual, None, ids, box=s.box)


def test_cli_query_drop_and_neighbours_from(tmp_path, shipped_corpus, world, capsys):
    from ratouch.cli import main

    def query(s, name, *extra):
        Image.fromarray(s.visual).save(tmp_path / f"{name}v.png")
        Image.fromarray(s.tactile).save(tmp_path / f"{name}t.png")
        code = main(["query", "--vision", str(tmp_path / f"{name}v.png"), "--tactile",
                     str(tmp_path / f"{name}t.png"), "--box", ",".join(map(str, s.box)),
                     "--corpus", str(shipped_corpus), *extra])
        return code, capsys.readouterr()

    code, out = query(world.sample("test", 190), "a")
    first = json.loads(out.out)
    ids = [n["id"] for n in first["neighbours"]["joint"]]
    assert "regenerated" not in first
    code, out = query(world.sample("test", 190), "a", "--drop", f"{ids[0]},{ids[3]}")
    r = json.loads(out.out)
    assert code == 0
    assert [n["id"] for n in r["regenerated"]["neighbours"]] == [ids[1], ids[2], ids[4]]
    assert r["regenerated"]["description"]["ra_touch"]
    (tmp_path / "first.json").write_text(json.dumps(first))
    code, out = query(world.sample("test", 40), "b", "--neighbours-from",
                      str(tmp_path / "first.json"))
    assert [n["id"] for n in json.loads(out.out)["regenerated"]["neighbours"]] == ids
    (tmp_path / "ids.json").write_text(json.dumps(ids[:2]))
    code, out = query(world.sample("test", 40), "b", "--neighbours-from",
                      str(tmp_path / "ids.json"), "--drop", str(ids[1]))
    assert [n["id"] for n in json.loads(out.out)["regenerated"]["neighbours"]] == ids[:1]
    code, out = query(world.sample("test", 40), "b", "--drop", "999999")
    assert code == 2 and "--drop" in out.err
    (tmp_path / "junk.json").write_text('{"neighbours": 3}')
    code, out = query(world.sample("test", 40), "b", "--neighbours-from",
                      str(tmp_path / "junk.json"))
    assert code == 2 and "neighbours-from" in out.err


def test_cached_default_corpus_is_embedded_again_after_retraining(tmp_path, monkeypatch,
                                                                  debug_checkpoints, caplog):
    """The shipped encoder is retrained: the user's cached corpus is re-embedded (not served
    with the old weights' embeddings), and so is one embedded before weights were recorded."""
    from ratouch.encoders import factory
    from ratouch.serve import pipeline as pl

    monkeypatch.setenv("RATOUCH_CACHE", str(tmp_path))
    shipped = {"folder": debug_checkpoints[0]}
    monkeypatch.setattr(factory, "shipped_weights", lambda name: shipped["folder"])
    folder = pl.default_corpus("debug", size="20", progress=False)
    manifest = folder / "embeddings" / "debug" / "manifest.json"
    first = json.loads(manifest.read_text())
    assert first["encoder_weights"] == factory.shipped_fingerprint("debug")

    shipped["folder"] = debug_checkpoints[1]  # retrained
    with caplog.at_level("INFO", logger="ratouch.serve.pipeline"):
        assert pl.default_corpus("debug", size="20", progress=False) == folder
    assert "re-embedding the default corpus" in caplog.text
    second = json.loads(manifest.read_text())
    assert second["encoder_weights"] == factory.shipped_fingerprint("debug")
    assert second["image_sha256"] != first["image_sha256"]
    pl.open_retriever(folder, "debug")  # embeddings and index agree with the new weights

    embed_and_index = pl.embed_and_index
    monkeypatch.setattr(pl, "embed_and_index", lambda *a, **k: pytest.fail("re-embedded"))
    pl.default_corpus("debug", size="20", progress=False)  # up to date: kept
    monkeypatch.setattr(pl, "embed_and_index", embed_and_index)
    manifest.write_text(json.dumps({k: v for k, v in second.items() if k != "encoder_weights"}))
    pl.default_corpus("debug", size="20", progress=False)  # made before weights were recorded
    assert json.loads(manifest.read_text())["encoder_weights"] == second["encoder_weights"]
