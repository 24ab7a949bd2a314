"""The RA-Touch query pipeline (shipped weights) and `ratouch query`, as a user meets them;
the query path itself (a request decoded once, answered alone or in a batch, the result's
JSON) also on the debug pipeline, which needs no trained weights."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from PIL import Image

from ratouch.errors import ConfigError, DataError
from ratouch.serve.request import QueryRequest, QueryResult, answer_one


def test_query_returns_every_documented_field(pipeline, world):
    s = world.sample("test", 120)
    r = pipeline.query(s.visual, s.tactile, box=s.box, k=5, label=s.caption)
    assert set(r["neighbours"]) == {"image", "tactile", "joint", "gated", "adapted"}
    for items in r["neighbours"].values():
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


def test_the_box_used_is_whole_pixels_clipped_to_the_image(world):
    """The box a request carries (and the result reports) is the one cropped: fractions
    widened to whole pixels, a box reaching outside clipped, each said once."""
    s = world.sample("test", 150)  # a 128x128 render
    r = QueryRequest.decode(s.visual, s.tactile, box=(10.5, 20.2, 100.7, 120.1))
    assert r.box == (10, 20, 101, 121)
    assert r.warnings == ("contact box [10.5, 20.2, 100.7, 120.1] used as [10, 20, 101, 121] "
                          "(whole pixels)",)
    r = QueryRequest.decode(s.visual, s.tactile, box=(-50, 0, 64, 64))
    assert r.box == (0, 0, 64, 64)
    assert r.warnings == ("contact box [-50, 0, 64, 64] used as [0, 0, 64, 64] (whole pixels, "
                          "clipped to the image)",)
    assert QueryRequest.decode(s.visual, s.tactile, box=(1, 2, 30, 40)).warnings == ()


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
    s, other = world.sample("test", 180), world.sample("test", 30)
    r = pipeline.query(s.visual, s.tactile, box=s.box, k=5)
    ids = [n["id"] for n in r["neighbours"]["joint"]]
    request = QueryRequest.decode(s.visual, s.tactile, box=s.box)
    same = pipeline.regenerate(request, ids)
    assert same["description"]["ra_touch"] == r["description"]["ra_touch"]
    assert same["attention"] == r["attention"]
    assert [n["id"] for n in same["neighbours"]] == ids
    assert [n["score"] for n in same["neighbours"]] == pytest.approx(
        [n["score"] for n in r["neighbours"]["joint"]], abs=2e-4)
    kept = pipeline.regenerate(request, ids[:2])
    assert len(kept["attention"]["text"]) == 2
    assert sum(kept["attention"]["image"]) == pytest.approx(1.0, abs=1e-3)
    swapped_ids = [n["id"] for n in pipeline.query(other.visual, other.tactile,
                                                   box=other.box)["neighbours"]["joint"]]
    swapped = pipeline.regenerate(request, swapped_ids)
    assert [n["id"] for n in swapped["neighbours"]] == swapped_ids
    # no neighbours at all: the integrator adds nothing, so p' is the baseline prompt
    assert pipeline.regenerate(request, [])["attention"] == {}
    for bad in ([len(pipeline.corpus)], [-1], [ids[0], ids[0]], ["3"]):
        with pytest.raises(ConfigError, match="neighbour ids"):
            pipeline.regenerate(request, bad)
    with pytest.raises(ConfigError, match="tactile"):
        pipeline.regenerate(QueryRequest.decode(s.visual, None, box=s.box), ids)


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
    from ratouch.search import retrieval_side as pl

    monkeypatch.setenv("RATOUCH_CACHE", str(tmp_path))
    shipped = {"folder": debug_checkpoints[0]}
    monkeypatch.setattr(factory, "shipped_weights", lambda name: shipped["folder"])
    folder = pl.default_corpus("debug", size="20", progress=False)
    manifest = folder / "embeddings" / "debug" / "manifest.json"
    first = json.loads(manifest.read_text())
    assert first["encoder_weights"] == factory.shipped_fingerprint("debug")

    shipped["folder"] = debug_checkpoints[1]  # retrained
    with caplog.at_level("INFO", logger="ratouch.search.retrieval_side"):
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


# --- the query path on the debug pipeline (no trained weights needed) -------------------------

def test_a_request_is_decoded_once_and_says_what_it_assumed(world, tmp_path):
    s = world.sample("test", 60)
    Image.fromarray(s.visual).save(tmp_path / "v.png")
    req = QueryRequest.decode(tmp_path / "v.png", s.tactile, k=3, label="soft", model="m")
    assert req.crop.dtype == np.uint8 and req.crop.ndim == 3 and req.frame.shape == s.tactile.shape
    assert req.background is None and (req.k, req.label, req.model) == (3, "soft", "m")
    assert req.warnings == ("no contact box given: used TVL's centred crop [48, 48, 81, 81]",)
    assert req.decode_ms >= 0
    alone = QueryRequest.decode(s.visual, None, box=s.box, background=s.tactile)
    assert alone.frame is None and alone.background is None and len(alone.warnings) == 2
    for bad in (0, 2.5, True):
        with pytest.raises(ConfigError, match="K must be a whole number"):
            QueryRequest.decode(s.visual, k=bad)
    with pytest.raises(DataError, match="background"):
        QueryRequest.decode(s.visual, s.tactile, background=np.zeros((9, 9, 3), np.uint8))


def test_answer_is_query_and_batches_match_single_answers(debug_pipeline, world):
    pipe = debug_pipeline
    samples = [world.sample("test", i) for i in (60, 140, 290)]
    requests = [QueryRequest.decode(s.visual, s.tactile, box=s.box, k=k, label=s.caption)
                for s, k in zip(samples, (5, 3, 4))]
    requests += [QueryRequest.decode(samples[0].visual, k=2),  # image-only
                 dataclasses.replace(QueryRequest.decode(samples[0].visual),  # past MAX_K:
                                     k=len(pipe.corpus.entries) + 1)]  # the answerer's check
    batch = pipe.answer(requests)
    assert isinstance(batch[-1], ConfigError) and "K must be a whole number" in str(batch[-1])
    for req, got in zip(requests[:-1], batch[:-1]):
        assert isinstance(got, QueryResult)
        alone = answer_one(pipe, req).to_dict()
        got = got.to_dict()
        assert got["timings_ms"]["batch_size"] == 4 and alone["timings_ms"]["batch_size"] == 1
        assert got["timings_ms"]["decode"] == req.decode_ms
        for key in ("description", "attention", "warnings", "box", "encoder", "visual_route",
                    "trust"):
            assert got[key] == alone[key], key
        assert [n["id"] for ns in got["neighbours"].values() for n in ns] == \
            [n["id"] for ns in alone["neighbours"].values() for n in ns]
        assert len(got["neighbours"]["image"]) == req.k
    s = samples[0]
    once = pipe.query(s.visual, s.tactile, box=s.box, k=5, label=s.caption)
    again = batch[0].to_dict()
    assert list(once) == ["neighbours", "description", "attention", "pca", "timings_ms",
                          "warnings", "box", "encoder", "visual_route", "trust", "retrieval"]
    # the same request alone: the same answer (a batch's floats differ in the last bits)
    assert {k: v for k, v in once.items() if k not in ("timings_ms", "pca")} == \
        {k: v for k, v in again.items() if k not in ("timings_ms", "pca")}
    assert [p["role"] for p in once["pca"]["points"]] == \
        [p["role"] for p in again["pca"]["points"]]
    assert once["warnings"][-1].startswith("no trust calibration for encoder debug")
    json.dumps(once)


def test_regenerate_reads_the_decoded_request(debug_pipeline, world):
    s = world.sample("test", 190)
    request = QueryRequest.decode(s.visual, s.tactile, box=s.box)
    r = answer_one(debug_pipeline, request)
    ids = [n["id"] for n in r.neighbours["joint"]]
    same = debug_pipeline.regenerate(request, ids)
    assert same["description"]["ra_touch"] == r.description["ra_touch"]
    assert same["attention"] == r.attention and [n["id"] for n in same["neighbours"]] == ids
    assert debug_pipeline.model() is debug_pipeline and debug_pipeline.name == "debug"
    with pytest.raises(ConfigError, match="unknown model"):
        debug_pipeline.model("default-b")
