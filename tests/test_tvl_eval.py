"""The TVL benchmark protocol on the world's test split, and the paired t-test between systems."""

from __future__ import annotations

import json

import pytest

from ratouch.errors import ConfigError, DataError
from ratouch.eval.judge import subset_of
from ratouch.eval.tvl import paired_ttest, run_tvl
from ratouch.world.dataset import world_for
from ratouch.world.splits import encode_test_split
from ratouch.world.tactile import sensor_family


@pytest.fixture(scope="module")
def split(pipeline):
    return encode_test_split(pipeline.encoders, indices=[0, 5, 45, 46, 100, 200, 300, 401])


def test_results_are_in_the_tvl_format_with_subsets(pipeline, split):
    records, summary = run_tvl(pipeline, "ra-touch", k=3, split=split)
    assert len(records) == 8
    for r in records:
        assert {"image_fp", "tactile_fp", "label", "generated response", "prompt",
                "offline_score"} <= set(r)
        assert 1.0 <= r["offline_score"] <= 10.0 and len(r["neighbours"]) == 3
    assert [subset_of(r["image_fp"]) for r in records] == ["SSVTP"] * 3 + ["HCT"] * 5
    assert summary["subsets"]["SSVTP"]["n"] == 3 and summary["subsets"]["HCT"]["n"] == 5
    # each record names its frame's sensor family; the summary has the judge's mean per family
    world = world_for(split.world)
    families = [sensor_family(world.sample("test", i).sensor) for i in split.indices]
    assert [r["sensor_family"] for r in records] == families == split.families
    fam = summary["families"]
    assert set(fam) == set(families) and sum(s["n"] for s in fam.values()) == 8
    for name, s in fam.items():
        mine = [r["offline_score"] for r in records if r["sensor_family"] == name]
        assert s["mean"] == pytest.approx(sum(mine) / len(mine))
    base, _ = run_tvl(pipeline, "baseline", split=split)
    assert "neighbours" not in base[0]
    with pytest.raises(ConfigError):
        run_tvl(pipeline, "gpt-5", split=split)


def _recs(scores, subset="ssvtp"):
    return [{"image_fp": f"{subset}/vision/{i}.png", "tactile_fp": f"{subset}/tactile/{i}.png",
             "label": "soft", "generated response": "soft", "offline_score": s}
            for i, s in enumerate(scores)]


def test_paired_ttest_pairs_by_sample_and_reports_per_subset():
    a = _recs([5, 6, 7, 5]) + _recs([4, 4, 5], "hct")
    b = _recs([6, 7, 8, 6]) + _recs([4, 5, 5], "hct")
    r = paired_ttest(a, list(reversed(b)))  # order does not matter: paired by file paths
    assert r["n_shared"] == 7
    assert r["subsets"]["SSVTP"]["diff"] == pytest.approx(1.0)
    assert r["subsets"]["SSVTP"]["p"] == pytest.approx(0.0, abs=1e-6) or \
        r["subsets"]["SSVTP"]["p"] < 1e-3
    assert r["subsets"]["overall"]["n"] == 7
    same = paired_ttest(a, a)
    assert same["subsets"]["overall"]["p"] == 1.0 and same["subsets"]["overall"]["diff"] == 0
    with pytest.raises(DataError):
        paired_ttest(_recs([1, 2]), _recs([1, 2], "hct"))  # nothing shared
    with pytest.raises(DataError):
        paired_ttest([{"label": "x", "generated response": "y"}], _recs([1]))  # no scores


def test_cli_ttest(tmp_path, capsys):
    from ratouch.cli import main

    fa, fb = tmp_path / "a.json", tmp_path / "b.json"
    fa.write_text(json.dumps(_recs([5, 6, 7, 5])))
    fb.write_text(json.dumps(_recs([6, 7, 8, 6])))
    assert main(["eval", "ttest", str(fa), str(fb)]) == 0
    out = capsys.readouterr().out
    assert "SSVTP" in out and "+1.000" in out
    fb.write_text("not json")
    assert main(["eval", "ttest", str(fa), str(fb)]) == 2


def test_validation_pairs_come_from_the_train_split_beyond_every_training_set(pipeline):
    from ratouch.world.splits import VALIDATION_START, encode_validation_split

    val = encode_validation_split(pipeline.encoders, n=3)
    world = world_for(val.world)
    assert val.split == "train" and val.indices == [VALIDATION_START + i for i in range(3)]
    assert val.labels == [world.sample("train", i).caption for i in val.indices]
    assert val.image_fp(0).endswith(f"/vision/train_{VALIDATION_START:06d}.png")
    assert val.tactile_fp(0).endswith(f"/tactile/train_{VALIDATION_START:06d}.png")
    test = encode_test_split(pipeline.encoders, indices=[0])
    assert test.image_fp(0).endswith("/vision/test_000000.png")
    with pytest.raises(ConfigError):
        encode_validation_split(pipeline.encoders, n=0)


def test_cli_eval_tvl_judges_the_validation_pairs_when_asked(pipeline, tmp_path, capsys,
                                                            monkeypatch):
    import ratouch.cli.eval as cli_eval
    from ratouch.cli import main
    from ratouch.world.splits import VALIDATION_START, encode_validation_split

    asked = []

    def small(encoders, world=None):
        asked.append(world)
        return encode_validation_split(encoders, world, n=3)

    monkeypatch.setattr(cli_eval, "_pipeline_on_lm", lambda args: pipeline)
    monkeypatch.setattr(cli_eval, "encode_validation_split", small)
    out = tmp_path / "val.json"
    assert main(["eval", "tvl", "--system", "baseline", "--validation", "--out", str(out),
                 "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    records = json.loads(out.read_text())
    assert len(asked) == 1 and summary["split"] == "validation" and summary["n"] == 3
    assert [r["image_fp"].rsplit("/", 1)[1] for r in records] == \
        [f"train_{VALIDATION_START + i:06d}.png" for i in range(3)]
    assert main(["eval", "tvl", "--system", "baseline", "--validation", "--out", str(out)]) == 0
    assert f"validation pairs (train[{VALIDATION_START}:" in capsys.readouterr().out
