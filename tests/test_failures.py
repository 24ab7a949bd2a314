"""Failure cases (`ratouch.eval.failures`): the table over a fake pipeline with a known retrieval
(precision, `joint_loses`, judge scores checked by hand), the stress conditions, the cache, the
filters; and (slow, when the trained assets exist) a few cases with the real pipeline."""

from __future__ import annotations

import json
import threading
from types import SimpleNamespace

import numpy as np
import pytest

from ratouch.errors import ConfigError, DataError
from ratouch.eval import failures
from ratouch.eval.judge import OfflineJudge
from ratouch.world.config import WorldConfig
from ratouch.world.material import MATERIALS

INDICES = [0, 5, 45, 46, 100, 300]  # structured (< 46) and wild samples
CONDS = ("natural", "noisy touch")


class FakeEncoders:
    name = "fake"
    dim = 4

    def encode_image(self, crops):
        return np.array([[c.mean(), c.std(), c[..., 0].mean(), 1.0] for c in crops], np.float32)

    def encode_tactile(self, frames, backgrounds=None):  # the frames decide; backgrounds unused
        return np.array([[f.std(), f.mean(), 1.0, f[..., 1].mean()] for f in frames],
                        np.float32)


class FakeCorpus:
    """Entries of every world material; `search` returns ids from the query's features, so
    image, tactile and joint queries retrieve different entries."""

    def __init__(self, n: int = 50):
        names = sorted(m.name for m in MATERIALS)
        self.entries = [SimpleNamespace(material=names[i % len(names)],
                                        caption="hard, smooth, cool, rigid, glossy")
                        for i in range(n)]
        self.manifest = {"metadata_sha256": "fake-corpus"}
        self.searches: list[np.ndarray] = []

    def search(self, key, q, k):
        self.searches.append(q)
        start = (np.abs(q).sum(1).astype(np.int64) * 7) % (len(self.entries) - k)
        ids = start[:, None] + np.arange(k)[None]
        return np.ones(ids.shape, np.float32), ids


class FakeGenerator:
    def __init__(self, text: str):
        self.text, self.calls = text, 0

    def describe(self, V, T, rv=None, rl=None):
        self.calls += 1
        return [self.text] * len(V)


class FakePipeline:
    def __init__(self):
        self.encoders = FakeEncoders()
        self.corpus = FakeCorpus()
        self.generator_base = FakeGenerator("hard, smooth")
        self.generator_ra = FakeGenerator("soft, fuzzy, fabric")

    def joint_query(self, V, T, gated=False, adapted=False):
        if adapted:
            return np.asarray(T, np.float32)
        return (V + (1 if gated else 2) * T).astype(np.float32)

    def neighbour_embeddings(self, ids):
        z = np.zeros((*ids.shape, self.encoders.dim), np.float32)
        return z, z


@pytest.fixture
def fake():
    return FakePipeline()


def test_rows_hold_scores_precisions_and_the_joint_verdict(fake):
    rows = failures.failure_cases(fake, k=3, conditions=CONDS, indices=INDICES)
    assert len(rows) == len(CONDS) * len(INDICES)
    assert [(r["condition"], r["index"]) for r in rows[:2]] == [("natural", 0), ("natural", 5)]
    judge = OfflineJudge()
    mats = np.array([e.material for e in fake.corpus.entries])
    # the searches in order per condition: RA-Touch's joint one, then image, tactile, gated,
    # adapted
    q_joint, q_image, q_tac, q_gated, q_adapted = fake.corpus.searches[:5]
    ids = {m: fake.corpus.search("text", q, 3)[1]
           for m, q in (("joint", q_joint), ("image", q_image), ("tactile", q_tac),
                        ("gated", q_gated), ("adapted", q_adapted))}
    first = rows[:len(INDICES)]  # one system's answers are judged together (its word rates)
    ra_scores = judge.score_many([(r["label"], r["ra_touch"]) for r in first])
    for j, r in enumerate(first):
        assert r["subset"] == ("structured" if r["index"] < 46 else "wild")
        for mode in failures.MODES:
            expected = float(np.mean(mats[ids[mode][j]] == r["material"]))
            assert r[f"precision_{mode}"] == pytest.approx(expected, abs=1e-4), mode
        best = max(r["precision_image"], r["precision_tactile"])
        assert r["joint_loses"] == (r["precision_joint"] < best)
        assert r["joint_gap"] == pytest.approx(best - r["precision_joint"], abs=1e-4)
        assert r["ra_touch"] == "soft, fuzzy, fabric" and r["baseline"] == "hard, smooth"
        assert r["ra_score"] == pytest.approx(ra_scores[j], abs=1e-3)
        assert r["ra_delta"] == pytest.approx(r["ra_score"] - r["baseline_score"], abs=2e-3)
    json.dumps(rows)


def test_conditions_change_the_inputs_and_cases_can_be_rebuilt():
    from ratouch.world.sampler import World

    natural = failures.case_sample("natural", 100)
    noisy = failures.case_sample("noisy touch", 100)
    expected = World(WorldConfig().with_stress(tactile_noise=0.2)).sample("test", 100)
    assert noisy.caption == expected.caption and np.array_equal(noisy.tactile, expected.tactile)
    assert not np.array_equal(natural.tactile, noisy.tactile)
    case = failures.case_sample("box offset", 100)  # what the app opens a row with
    background = failures.case_world("box offset").background_image(case.sensor)
    offset_world = World(WorldConfig().with_stress(box_offset=1.0))
    offset = offset_world.sample("test", 100)
    assert tuple(case.box) == tuple(offset.box) != tuple(offset.box_true)
    assert case.caption == offset.caption
    assert np.array_equal(case.visual, offset.visual)
    assert np.array_equal(case.tactile, offset.tactile)
    assert np.array_equal(background, offset_world.background_image(offset.sensor))
    small = failures.condition_world(WorldConfig(seed=3), "small object + dominant background")
    assert small.seed == 3 and small.stress.object_scale == 0.12
    with pytest.raises(ConfigError, match="unknown condition"):
        failures.case_sample("moonlight", 1)
    with pytest.raises(DataError, match="out of range"):
        failures.case_sample("natural", 402)
    with pytest.raises(DataError, match="integer"):
        failures.case_sample("natural", "x")


def test_the_table_is_cached_once_and_keyed_by_its_settings(fake, tmp_path, monkeypatch):
    monkeypatch.setenv("RATOUCH_CACHE", str(tmp_path))
    opts = dict(k=2, conditions=("natural",), indices=INDICES[:3])
    assert failures.load_or_compute(fake, cached_only=True, **opts) is None
    seen = []
    tables = []
    threads = [threading.Thread(target=lambda: tables.append(failures.load_or_compute(
        fake, progress=lambda f, what: seen.append(f), **opts))) for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert fake.generator_ra.calls == 1  # three sessions asked, the table was computed once
    assert seen[0] == 0 and seen[-1] == 1.0
    path = failures.cache_path(fake, **opts)
    assert path.parent == tmp_path / "failures" and path.name.startswith("fake-")
    assert all(t["rows"] == tables[0]["rows"] for t in tables) and len(tables[0]["rows"]) == 3
    assert tables[0]["meta"]["path"] == str(path) and tables[0]["meta"]["seconds"] >= 0
    again = failures.load_or_compute(fake, cached_only=True, **opts)
    assert again["rows"] == tables[0]["rows"] and fake.generator_ra.calls == 1
    assert failures.cache_path(fake, **{**opts, "k": 3}) != path
    assert failures.cache_path(fake, **{**opts, "conditions": ("noisy touch",)}) != path
    fake.corpus.manifest = {"metadata_sha256": "another corpus"}
    assert failures.cache_path(fake, **opts) != path  # a rebuilt corpus is a new table
    fake.corpus.manifest = {"metadata_sha256": "fake-corpus"}
    path.write_text("{ truncated")  # an unreadable cache is recomputed, not an error
    assert failures.load_or_compute(fake, cached_only=True, **opts) is None
    assert len(failures.load_or_compute(fake, **opts)["rows"]) == 3
    assert fake.generator_ra.calls == 2


def _row(cond, i, subset, ra, base, pi, pt, pj):
    best = max(pi, pt)
    return {"condition": cond, "index": i, "subset": subset, "ra_score": ra,
            "label": "hard, smooth", "ra_touch": "hard, smooth, flat", "baseline": "soft",
            "baseline_score": base, "ra_delta": ra - base, "precision_image": pi,
            "precision_tactile": pt, "precision_joint": pj, "precision_gated": pj,
            "precision_adapted": pt,
            "best_unimodal": best, "joint_gap": best - pj, "joint_loses": pj < best}


def test_views_filter_and_sort():
    rows = [_row("natural", 0, "structured", 3.0, 5.0, 0.2, 0.6, 0.4),
            _row("natural", 50, "wild", 2.0, 2.0, 0.2, 0.2, 0.8),
            _row("noisy touch", 50, "wild", 2.0, 6.0, 1.0, 0.0, 0.0),
            _row("noisy touch", 60, "wild", 9.0, 9.0, 0.0, 0.3, 0.2)]
    low = failures.select_cases(rows, view="ra_lowest")
    assert [(r["condition"], r["index"]) for r in low] == [
        ("noisy touch", 50), ("natural", 50), ("natural", 0), ("noisy touch", 60)]
    loses = failures.select_cases(rows, view="joint_loses")
    assert [(r["condition"], r["index"]) for r in loses] == [
        ("noisy touch", 50), ("natural", 0), ("noisy touch", 60)]
    assert [r["index"] for r in failures.select_cases(rows, subset="structured")] == [0]
    assert len(failures.select_cases(rows, condition="noisy touch", limit=1)) == 1
    for bad in (dict(view="best"), dict(subset="indoor"), dict(condition="fog")):
        with pytest.raises(ConfigError):
            failures.select_cases(rows, **bad)
    summary = failures.summarise(rows)
    assert [(s["condition"], s["subset"]) for s in summary] == [
        ("natural", "all"), ("natural", "structured"), ("natural", "wild"),
        ("noisy touch", "all")]  # one subset only: no repeated row
    assert summary[0]["joint_loses"] == 0.5 and summary[0]["ra_score"] == 2.5
    lo, hi = summary[0]["ra_delta_ci"]  # the paired difference's bootstrap CI holds its mean
    assert lo <= summary[0]["ra_delta"] <= hi
    assert summary[0]["ra_f1"] == pytest.approx(0.8) and summary[0]["baseline_f1"] == 0.0
    assert summary[0]["ra_mean_length"] == 3 and summary[0]["baseline_mean_length"] == 1
    # a table computed before a mode was registered: that mode's precision is None
    before = [{k: v for k, v in r.items() if k != "precision_adapted"} for r in rows]
    assert failures.summarise(before)[0]["precision_adapted"] is None


def test_judge_scores_of_a_query_result():
    judge = OfflineJudge()
    scores = failures.judge_scores("hard, smooth, cool", {"ra_touch": "hard, smooth, cool",
                                                         "baseline": "soft, fuzzy"}, judge)
    assert scores["ra_touch"] > scores["baseline"] >= 1
    assert failures.judge_scores(None, {"ra_touch": "hard"}, judge) == {}
    assert failures.judge_scores("hard", {"ra_touch": ""}, judge) == {"ra_touch": None}


def test_bad_settings_are_refused(fake):
    with pytest.raises(ConfigError, match="unknown condition"):
        failures.failure_cases(fake, conditions=("fog",))
    with pytest.raises(ConfigError, match="K must be"):
        failures.failure_cases(fake, k=0, conditions=CONDS)
    fake.corpus.entries = [SimpleNamespace(material="", caption="x")] * 10
    with pytest.raises(DataError, match="material"):
        failures.failure_cases(fake, conditions=CONDS, indices=[0])


@pytest.mark.slow
def test_real_pipeline_failure_cases(real_pipeline):
    pipe = real_pipeline
    table = failures.load_or_compute(pipe, conditions=("natural", "noisy touch"),
                                     indices=[0, 60, 200])
    rows = table["rows"]
    assert len(rows) == 6 and all(r["ra_touch"] and r["baseline"] for r in rows)
    assert all(1 <= r["ra_score"] <= 10 and 0 <= r["precision_joint"] <= 1 for r in rows)
    # a case rebuilt from its (condition, index) gives the table's RA-Touch description
    r = rows[4]
    case = failures.case_sample(r["condition"], r["index"])
    background = failures.case_world(r["condition"]).background_image(case.sensor)
    label = case.caption
    out = pipe.query(case.visual, case.tactile, box=tuple(int(v) for v in case.box), k=5,
                     label=label, background=background)
    assert label == r["label"] and out["description"]["ra_touch"] == r["ra_touch"]
