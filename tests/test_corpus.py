"""ImageNet-T: stratified subsets, recaptioned captions, real lists, integrity checks."""

from __future__ import annotations

import collections
import json

import numpy as np
import pytest
from PIL import Image

from ratouch.corpus.imagenet_t import (
    build_corpus,
    load_corpus,
    parse_size,
    stratified_rows,
    stratified_world_ids,
    world_lexicon,
)
from ratouch.corpus.recaption import OfflineRecaptioner, validate_caption
from ratouch.errors import ConfigError, DataError, DataNotFoundError
from ratouch.world.config import WorldConfig
from ratouch.world.material import material
from ratouch.world.objects import OBJECT_CLASSES
from ratouch.world.sampler import CORPUS_MAX_PER_CLASS, CORPUS_POOL_PER_CLASS, World


def test_parse_size():
    assert parse_size("10k") == 10_000 and parse_size("150K") == 150_000
    assert parse_size("1m") == 1_000_000 and parse_size("2500") == 2500
    for bad in ("-5", "ten", "0", ""):
        with pytest.raises(ConfigError):
            parse_size(bad)


def test_subsets_are_stratified_and_nested():
    small = stratified_world_ids(10_000, seed=0)
    big = stratified_world_ids(50_000, seed=0)
    assert len(small) == 10_000 and len(set(small)) == 10_000
    assert set(small) <= set(big)
    per_class = collections.Counter(c for c, _ in small)
    assert len(per_class) == len(OBJECT_CLASSES)
    assert max(per_class.values()) - min(per_class.values()) <= 1
    assert len(stratified_world_ids(150_000, seed=0)) == 150_000
    with pytest.raises(ConfigError, match="pool"):
        stratified_world_ids(20_000_000, seed=0)


def test_corpora_past_the_pool_extend_it_and_hold_all_of_it():
    pool = len(OBJECT_CLASSES) * CORPUS_POOL_PER_CLASS
    full, past = stratified_world_ids(pool, seed=0), stratified_world_ids(pool + 500, seed=0)
    assert set(full) == {(c, i) for c in range(len(OBJECT_CLASSES))
                         for i in range(CORPUS_POOL_PER_CLASS)}
    extra = set(past) - set(full)
    assert len(past) == len(set(past)) == pool + 500 and len(extra) == 500
    per_class = collections.defaultdict(set)
    for c, i in past:
        per_class[c].add(i)
    assert all(got == set(range(len(got))) for got in per_class.values())  # the next ones
    world = World(WorldConfig(seed=0))
    a, b = world.corpus_image(3, CORPUS_POOL_PER_CLASS), world.corpus_image(3, 5_000)
    assert a.shape == b.shape and not np.array_equal(a, b)
    with pytest.raises(ConfigError, match="instance"):
        world.corpus_image(3, CORPUS_MAX_PER_CLASS)


def test_build_world_corpus(tmp_path, world):
    manifest = build_corpus(tmp_path / "c", 600, seed=0, progress=False)
    assert manifest["size"] == 600 and manifest["n_classes"] == len(OBJECT_CLASSES)
    m2, entries = load_corpus(tmp_path / "c")
    assert m2 == manifest
    for e in entries:
        assert len(validate_caption(e.caption)) == 5
        assert e.class_name in e.description
        # the description says how the material looks, never which look-alike it is
        assert material(e.material).look.word in e.description
    src = entries[7].source.split(":")
    img = world.corpus_image(int(src[2]), int(src[3]))
    assert img.shape == (128, 128, 3)
    with pytest.raises(ConfigError, match="already holds"):
        build_corpus(tmp_path / "c", 10, progress=False)


def test_offline_captions_follow_what_is_visible():
    rc = OfflineRecaptioner(world_lexicon())
    soft = rc.recaption("teddy", "a brown furry teddy on a wooden surface")
    hard = rc.recaption("frying pan", "a black cast iron frying pan on a woven surface")
    assert {"soft", "furry", "plush", "fluffy"} & set(soft)
    assert {"hard", "metallic", "rigid", "solid"} & set(hard)


def test_tampered_or_missing_corpus_is_refused(tmp_path):
    build_corpus(tmp_path / "c", 200, progress=False)
    meta = tmp_path / "c" / "metadata.jsonl"
    lines = meta.read_text().splitlines()
    row = json.loads(lines[0])
    row["caption"] = "soft, soft, soft, soft, soft"
    meta.write_text("\n".join([json.dumps(row)] + lines[1:]) + "\n")
    with pytest.raises(DataError, match="checksum"):
        load_corpus(tmp_path / "c")
    with pytest.raises(DataNotFoundError):
        load_corpus(tmp_path / "empty")


def test_real_image_list(tmp_path):
    rows = []
    for i in range(12):
        p = tmp_path / f"img{i}.jpg"
        Image.fromarray(np.full((16, 16, 3), i * 10, np.uint8)).save(p)
        cls = ["sofa", "coffee mug", "mitten"][i % 3]
        rows.append(f"{p.name},{cls},a photo of a {cls}")
    (tmp_path / "list.csv").write_text("path,class,caption\n" + "\n".join(rows) + "\n")
    manifest = build_corpus(tmp_path / "real", 6, image_list=str(tmp_path / "list.csv"),
                            progress=False)
    _, entries = load_corpus(tmp_path / "real")
    assert manifest["size"] == 6 and manifest["n_classes"] == 3
    assert collections.Counter(e.class_name for e in entries) == {"sofa": 2, "coffee mug": 2,
                                                                  "mitten": 2}
    assert all(e.source.endswith(".jpg") and e.material == "" for e in entries)
    (tmp_path / "bad.csv").write_text("missing.jpg,sofa,a sofa\n")
    with pytest.raises(DataNotFoundError, match="missing.jpg"):
        build_corpus(tmp_path / "real2", 6, image_list=str(tmp_path / "bad.csv"), progress=False)
    assert not (tmp_path / "real2").exists()


def test_stratified_rows_balances_classes():
    rows = [(f"p{i}", "a" if i < 90 else "b", "x") for i in range(100)]
    picked = stratified_rows(rows, 20, seed=0)
    assert collections.Counter(r[1] for r in picked) == {"a": 10, "b": 10}


def test_caption_embeddings_encode_each_caption_once_and_match_the_encoder(debug_encoders):
    from ratouch.corpus.embed import CaptionEmbeddings

    seen = []

    class Counting:
        dim = debug_encoders.dim

        def encode_text(self, texts):
            seen.extend(texts)
            return debug_encoders.encode_text(texts)

    caps = ["soft, smooth", "hard, rough", "soft, smooth", "cold, hard", "hard, rough"]
    cache = CaptionEmbeddings(Counting(), limit=3)
    got = np.concatenate([cache(caps[:3]), cache(caps[3:])])
    np.testing.assert_allclose(got, debug_encoders.encode_text(caps), atol=1e-6)
    assert seen == ["soft, smooth", "hard, rough", "cold, hard"]  # none encoded twice
    cache(["wet, slick"])  # a fourth distinct caption: past the limit, the memory starts again
    assert list(cache.rows) == ["wet, slick"] and cache([]).shape == (0, debug_encoders.dim)
