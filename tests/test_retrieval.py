"""Embedding, indexing and retrieval in the paper's settings."""

from __future__ import annotations

import numpy as np
import pytest

from ratouch.corpus.embed import embed_corpus, load_embeddings
from ratouch.errors import ConfigError, DataError
from ratouch.eval.retrieval import evaluate_retrieval, split_queries
from ratouch.search.retrieval import CorpusIndex, CorpusSearch
from ratouch.world.config import WorldConfig


def test_embeddings_are_complete_and_checked(small_corpus, debug_encoders):
    img, txt, manifest = load_embeddings(small_corpus, "debug", 384)
    assert img.shape == txt.shape == (240, 384)
    assert np.allclose(np.linalg.norm(img, axis=1), 1, atol=1e-4)
    with pytest.raises(DataError, match="dimension"):
        load_embeddings(small_corpus, "debug", 768)


def test_interrupted_embedding_resumes_to_the_same_result(tmp_path, small_corpus, debug_encoders,
                                                          monkeypatch):
    import shutil

    from ratouch.corpus import embed as emb

    folder = tmp_path / "c"
    shutil.copytree(small_corpus, folder, ignore=shutil.ignore_patterns("embeddings", "index"))
    real = emb.corpus_images
    calls = {"n": 0}

    def flaky(entries, start, batch, workers, progress):
        for b in real(entries, start, batch, workers, progress):
            calls["n"] += 1
            if calls["n"] == 2:
                raise KeyboardInterrupt
            yield b

    monkeypatch.setattr(emb, "corpus_images", flaky)
    with pytest.raises(KeyboardInterrupt):
        embed_corpus(folder, debug_encoders, batch=100, workers=1, progress=False)
    assert (folder / "embeddings" / "debug" / "progress.json").is_file()
    monkeypatch.setattr(emb, "corpus_images", real)
    embed_corpus(folder, debug_encoders, batch=100, workers=1, progress=False)
    a = load_embeddings(folder, "debug")[0]
    b = load_embeddings(small_corpus, "debug")[0]
    assert np.allclose(a, b, atol=1e-5)


def test_retrieval_in_all_four_encoder_settings(small_corpus, debug_encoders, world):
    r = CorpusSearch(debug_encoders, CorpusIndex(small_corpus, "debug", 384))
    s = world.sample("test", 80)
    q = r.embed_queries([s.visual[s.box[1]:s.box[3], s.box[0]:s.box[2]]], [s.tactile],
                        [world.background_image(s.sensor)])
    res = r.retrieve(q, k=5)
    assert set(res) == {"image_image", "image_text", "tactile_image", "tactile_text"}
    for scores, ids in res.values():
        assert scores.shape == ids.shape == (1, 5)
        assert np.all(np.diff(scores[0]) <= 1e-6)
    nb = r.neighbours(*[x[0] for x in res["tactile_text"]])
    assert nb[0].caption.count(",") == 4 and nb[0].class_name
    assert r.corpus.thumbnail(nb[0].id, 64).shape[2] == 3
    with pytest.raises(ConfigError, match="K=241"):
        r.retrieve(q, k=241)
    with pytest.raises(ConfigError, match="joint"):
        r.retrieve(q, k=3, settings=["joint_text"])


def test_index_is_reused_and_a_mismatched_encoder_refused(small_corpus, debug_encoders):
    CorpusIndex(small_corpus, "debug", 384)
    idx_dir = small_corpus / "index" / "debug" / "text-flat"
    before = (idx_dir / "index.faiss").read_bytes()
    CorpusIndex(small_corpus, "debug", 384)  # loads, does not rebuild
    assert (idx_dir / "index.faiss").read_bytes() == before

    class Other:
        name, dim = "default-s", 384

    with pytest.raises(DataError, match="embedded with"):
        CorpusSearch(Other(), CorpusIndex(small_corpus, "debug", 384))


def test_retrieval_eval_reports_every_setting(small_corpus, debug_encoders):
    r = CorpusSearch(debug_encoders, CorpusIndex(small_corpus, "debug", 384))
    q = split_queries(WorldConfig(), n=60)
    out = evaluate_retrieval(r, queries=q, ks=(1, 5))
    assert set(out["settings"]) == {"image_image", "image_text", "tactile_image", "tactile_text"}
    m = out["settings"]["tactile_text"]["all"]["5"]
    # the reported P@5 is the share of the top-5 made of the query's material
    emb = r.embed_queries(q["crops"], q["tactiles"], q["backgrounds"])
    ids = r.retrieve(emb, 5, settings=["tactile_text"])["tactile_text"][1]
    mats = np.array([e.material for e in r.corpus.entries])
    want = np.mean(mats[ids] == np.asarray(q["materials"])[:, None])
    assert m["material_precision"] == pytest.approx(want, abs=1e-4)
    assert out["chance"]["5"]["material_precision"] < 0.2


@pytest.mark.slow
def test_joint_query_beats_the_image_query_on_look_alike_materials(real_pipeline):
    """Look-alike materials share their look, so the image query cannot tell them apart;
    touch can, and the Tactile-Guided Retriever's joint query must use it."""
    r = evaluate_retrieval(real_pipeline.retriever, ks=(5,),
                           joint_fn=real_pipeline.joint_query)
    p5 = {s: r["settings"][s]["look_alike"]["5"]["material_precision"]
          for s in ("image_text", "tactile_text", "joint_text")}
    assert p5["joint_text"] > p5["image_text"] + 0.1
    assert p5["image_text"] > r["chance"]["5"]["material_precision"]


# ------------------------------------------------------------------ the encoder's weights

@pytest.fixture
def tiny_corpus(tmp_path):
    from ratouch.corpus.imagenet_t import build_corpus

    folder = tmp_path / "tiny"
    build_corpus(folder, 20, seed=0, progress=False)
    return folder


def test_embeddings_made_with_other_weights_are_refused(tiny_corpus, debug_checkpoints):
    """A user corpus embedded before the encoder was retrained gives wrong neighbours: every
    way of opening it with the new weights says so instead."""
    from ratouch.encoders.factory import create_model
    from ratouch.search.retrieval_side import open_retriever

    old, new = (create_model("debug", pretrained=f) for f in debug_checkpoints)
    assert old.weights_fingerprint != new.weights_fingerprint
    manifest = embed_corpus(tiny_corpus, old, batch=10, workers=1, progress=False)
    assert manifest["encoder_weights"] == old.weights_fingerprint
    open_retriever(tiny_corpus, "debug", pretrained=debug_checkpoints[0])  # the same weights
    with pytest.raises(DataError, match="other debug weights") as err:
        open_retriever(tiny_corpus, "debug", pretrained=debug_checkpoints[1])
    assert "embed the corpus again" in str(err.value)
    with pytest.raises(DataError, match="other debug weights"):
        embed_corpus(tiny_corpus, new, batch=10, workers=1, progress=False)
    with pytest.raises(DataError, match="other debug weights"):
        load_embeddings(tiny_corpus, "debug", 384, weights=new.weights_fingerprint)
    with pytest.raises(DataError, match="other debug weights"):
        CorpusIndex(tiny_corpus, "debug", 384, weights=new.weights_fingerprint)


def test_embeddings_without_recorded_weights_load_with_a_warning(tiny_corpus, debug_checkpoints,
                                                                  caplog):
    import json

    from ratouch.encoders.factory import create_model

    enc = create_model("debug", pretrained=debug_checkpoints[0])
    embed_corpus(tiny_corpus, enc, batch=10, workers=1, progress=False)
    path = tiny_corpus / "embeddings" / "debug" / "manifest.json"
    legacy = json.loads(path.read_text())
    del legacy["encoder_weights"]  # as written before the weights were recorded
    path.write_text(json.dumps(legacy))
    with caplog.at_level("WARNING", logger="ratouch.corpus.embed"):
        search = CorpusSearch(enc, CorpusIndex(tiny_corpus, "debug", 384))
    assert len(search.corpus) == 20
    assert "do not record which encoder weights" in caplog.text


def test_an_index_of_older_embeddings_is_refused(tiny_corpus, debug_checkpoints):
    import shutil

    from ratouch.encoders.factory import create_model

    old, new = (create_model("debug", pretrained=f) for f in debug_checkpoints)
    embed_corpus(tiny_corpus, old, batch=10, workers=1, progress=False)
    CorpusIndex(tiny_corpus, "debug", 384)
    shutil.rmtree(tiny_corpus / "embeddings")  # embedded again, the index left behind
    embed_corpus(tiny_corpus, new, batch=10, workers=1, progress=False)
    with pytest.raises(DataError, match="embedded again since"):
        CorpusIndex(tiny_corpus, "debug", 384)


def test_a_partial_run_with_other_weights_starts_again(tiny_corpus, debug_checkpoints,
                                                       monkeypatch):
    import shutil

    from ratouch.corpus import embed as emb
    from ratouch.encoders.factory import create_model

    old, new = (create_model("debug", pretrained=f) for f in debug_checkpoints)
    reference = tiny_corpus.parent / "reference"
    shutil.copytree(tiny_corpus, reference)
    embed_corpus(reference, new, batch=10, workers=1, progress=False)
    real = emb.corpus_images

    def interrupted(entries, start, batch, workers, progress):
        yield next(real(entries, start, batch, workers, progress))
        raise KeyboardInterrupt

    monkeypatch.setattr(emb, "corpus_images", interrupted)
    with pytest.raises(KeyboardInterrupt):
        embed_corpus(tiny_corpus, old, batch=10, workers=1, progress=False)
    monkeypatch.setattr(emb, "corpus_images", real)
    embed_corpus(tiny_corpus, new, batch=10, workers=1, progress=False)  # not resumed
    got = load_embeddings(tiny_corpus, "debug", weights=new.weights_fingerprint)[0]
    want = load_embeddings(reference, "debug")[0]
    assert np.allclose(got, want, atol=1e-5)
