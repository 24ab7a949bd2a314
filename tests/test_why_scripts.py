"""The scripts/why_*.py checks behind docs/geometry.md and docs/premise.md, each run small on
the tests' pipeline."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest

from ratouch.paths import geometry_calibration

REPO = Path(__file__).resolve().parents[1]


def _script(name: str):
    """scripts/`name`.py as a module, registered under its name so that a script's functions
    can be sent to its worker processes (pickled by reference)."""
    spec = importlib.util.spec_from_file_location(name, REPO / "scripts" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
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


@pytest.mark.skipif(not geometry_calibration().is_file(), reason="no geometry calibration")
def test_world_firmness_check_reads_every_stream_and_the_criteria(capsys):
    """scripts/why_world_firmness.py, small: every family's balanced accuracy on the world's
    validation and test renders and on fresh everyday presses, Taxim's real balls read soft,
    and (with --after) the criteria missed; the shipped calibration against itself."""
    script = _script("why_world_firmness")
    assert script.main(["--per-kind", "1", "--world", "4", "--test", "30",
                        "--after", str(geometry_calibration())]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["before"] == out["after"]
    assert set(out["before"]) == {"digit", "gelsight", "mini"}
    for rec in out["before"].values():
        assert rec["world_validation"]["n"] == 4 and rec["everyday"]["n"] == 7
        assert 0 < rec["world_test"]["n"] <= 30
        assert 0 <= rec["everyday"]["balanced"] <= 1
    assert out["before"]["gelsight"]["real_balls"] == 48
    assert out["before"]["mini"]["real_balls"] == 24
    assert "real_balls" not in out["before"]["digit"]  # no real DIGIT ball presses
    assert isinstance(out["criteria_missed"], list)
    # the criteria as written: a world reading at chance is named
    chance = {"balanced": 0.5, "soft_recall": 0.5, "hard_recall": 0.5, "n": 10}
    good = {"balanced": 0.9, "soft_recall": 0.9, "hard_recall": 0.9, "n": 10}
    rec = {"world_validation": chance, "everyday": good, "real_balls_read_soft": 0}
    missed = script.verdict({"mini": {"everyday": good}}, {"mini": rec})
    assert len(missed) == 1 and "world validation" in missed[0]


class _Shipped:
    """Stands in for `RATouchPipeline` in a script: `load` gives the tests' real pipeline
    (the shipped default-s weights on the 600-entry corpus), not the default 10k corpus."""

    pipeline = None

    @classmethod
    def load(cls, *args, **kwargs):
        return cls.pipeline


@pytest.mark.slow
def test_retrieval_precision_check_reports_every_mode_per_group(real_pipeline, monkeypatch,
                                                                capsys):
    script, out = _run_on_shipped("why_retrieval_precision", ["4"], real_pipeline, monkeypatch,
                                  capsys)
    assert set(out) == {"seen", "scarce"}
    for r in out.values():
        assert "chance" in r
        for mode in script.QUERY_MODES:         # every mode's retrieval, by its target
            assert any(k.startswith(mode + "_") for k in r), mode
        assert all(0 <= v <= 1 for v in r.values())


@pytest.mark.slow
def test_oracle_neighbours_check_trains_and_judges_both_groups(real_pipeline, monkeypatch,
                                                               capsys):
    _, out = _run_on_shipped("why_oracle_neighbours", ["--n", "4", "--steps", "2", "--pairs", "48"],
                             real_pipeline, monkeypatch, capsys)
    assert set(out) == {"seen", "scarce"}
    for r in out.values():
        assert {"baseline", "perfect", "perfect_shuffled", "gain", "shuffle_drop"} <= set(r)
        assert 0 <= r["perfect"] <= 10


@pytest.mark.slow
def test_lr_trainables_check_trains_a_variant_and_says_whether_it_reads(real_pipeline,
                                                                        monkeypatch, capsys):
    _, out = _run_on_shipped("why_lr_trainables", ["--n", "4", "--steps", "2", "--pairs", "48",
                                                   "--variants", "integrator"],
                             real_pipeline, monkeypatch, capsys)
    assert out["config"]["stage2_steps"] == 2 and "integrator" in out["config"]["variants"]
    for g in ("seen", "scarce"):
        assert {"shipped", "integrator"} <= set(out[g])
        assert isinstance(out[g]["integrator"]["reads"], bool)


@pytest.mark.slow
def test_press_adapter_check_fits_its_arms_and_reads_both_regimes(real_pipeline, monkeypatch,
                                                                  capsys):
    _, out = _run_on_shipped("why_press_adapter", ["--fit", "1", "--world", "12", "--eval", "1",
                                                   "--world-eval", "8", "--steps", "3"],
                             real_pipeline, monkeypatch, capsys)
    assert out["config"]["steps"] == 3
    for arm in ("identity", "map", "shuffled", "everyday_only"):
        for fam in ("digit", "gelsight", "mini"):
            assert set(out[arm][fam]) == {"everyday_bg", "everyday_alone", "world"}
            assert all(0 <= v <= 1 for v in out[arm][fam].values())
    gain = out["map_gain"]
    assert gain["everyday_ci95"][0] <= gain["everyday"] <= gain["everyday_ci95"][1]


@pytest.mark.slow
def test_withhold_check_reads_its_three_measures(real_pipeline, monkeypatch, capsys):
    """scripts/why_withhold.py on the first 14 test pairs (one of them, 13, a DIGIT frame
    beyond the look check's caution but within every rendered unit, so not withheld): the
    flagged rows, the rule against gated, against the baseline with a neutral touch, and
    against paper on recoloured frames, each with its CI; and the fresh renders' count."""
    from ratouch.world.config import WorldConfig
    from ratouch.world.sensors import WITHHOLD_LIMIT, guess_family
    from ratouch.world.splits import world_for

    script, out = _run_on_shipped("why_withhold", ["--n", "14", "--fresh", "3"], real_pipeline,
                                  monkeypatch, capsys)
    assert out["config"]["n"] == 14 and out["config"]["withhold_limit"] == WITHHOLD_LIMIT
    assert out["natural"]["flagged_indices"] == []
    assert out["natural"]["rule_vs_gated"]["diff"] == 0
    world = world_for(WorldConfig())
    odd = [script.recoloured(world.sample("test", i).tactile) for i in range(14)]
    assert out["recoloured"]["flagged"] == sum(guess_family(f)[1] > WITHHOLD_LIMIT for f in odd)
    fresh = out["fresh_renders"]
    assert fresh["renders"] == 6 and fresh["beyond"] == sum(fresh["by_family"].values())
    for block, key in (("natural", "rule_vs_gated"), ("neutral_touch", "rule_vs_baseline"),
                       ("recoloured", "rule_vs_paper")):
        d = out[block][key]
        assert d["ci95"][0] <= d["diff"] <= d["ci95"][1]
    assert all(1 <= v <= 10 for v in (out["natural"]["gated"], out["neutral_touch"]["rule"],
                                      out["recoloured"]["paper"]))
    frame = np.full((8, 8, 3), (10, 100, 200), np.uint8)
    assert script.recoloured(frame)[0, 0].tolist() == [220, 11, 110]


@pytest.mark.slow
def test_withhold_check_of_the_fallback_system(real_pipeline, monkeypatch, capsys):
    """scripts/why_withhold.py --system fallback on the first 6 test pairs: the rule against
    `paper` on the natural split (nothing withheld, no difference), the serving path's answers
    identical to `paper`'s with and without the background, and the fifth measure (recoloured
    frames of another pair) with the fallback system between its parts."""
    _, out = _run_on_shipped("why_withhold", ["--system", "fallback", "--n", "6", "--fresh", "2",
                                              "--premise", "3"],
                             real_pipeline, monkeypatch, capsys)
    assert out["config"]["system"] == "fallback"
    assert len(out["measured"]) == 10 and out["commit"]  # what the app dates it by
    assert out["natural"]["rule_vs_fallback"]["diff"] == 0
    assert out["natural"]["fallback"] == out["natural"]["fallback_rule"]
    assert out["serving"] == {"queries": 12, "withheld": 0, "differ": [],
                              "differ_where_not_withheld": 0}
    bad = out["recoloured_other"]
    assert bad["flagged"] == out["recoloured"]["flagged"]  # the same frames, another order
    assert "fallback_rule" in out["recoloured"]
    for key in ("fallback_vs_baseline", "fallback_vs_paper"):
        assert bad[key]["ci95"][0] <= bad[key]["diff"] <= bad[key]["ci95"][1]
    assert all(1 <= bad[k] <= 10 for k in ("baseline", "paper", "gated_rule", "fallback"))
    assert {g: v["frames"] for g, v in out["premise_groups"].items()} == {"seen": 3, "scarce": 3}
    assert all(isinstance(v["beyond"], list) for v in out["premise_groups"].values())


@pytest.mark.slow
def test_withhold_uncertain_check_reads_five_ways_and_decides(real_pipeline, monkeypatch,
                                                              capsys, tmp_path):
    """scripts/why_withhold_uncertain.py on the first 8 test pairs: each pair read five ways,
    every row counted in a state, the natural split unchanged by the rule, the rule's answer
    only where the state is uncertain (or the look beyond the limit), each criterion's CI
    around its mean, and the verdict decided from them; the JSON file written."""
    from ratouch.world.sensors import family_sensors, sensor_family

    target = tmp_path / "r.json"
    script, out = _run_on_shipped("why_withhold_uncertain", ["--n", "8", "--serving", "3",
                                                             "--json", str(target)],
                                  real_pipeline, monkeypatch, capsys)
    assert len(out["measured"]) == 10 and out["commit"]  # when and on what it was measured
    # the serving path withholds where the shipped rule fires and nowhere else, and answers
    # as `paper` alone and with the pair's own background (test pair 2's blank: it fires)
    sv = out["serving"]
    assert sv["disagree"] == [] and sv["fires"] == sv["withheld"] >= 1
    assert sv["queries_a_b"] == 6 and sv["differ_from_paper_a_b"] == []
    assert json.loads(target.read_text()) == out
    assert list(out["conditions"]) == [c[0] for c in script.CONDITIONS]
    for rep in out["conditions"].values():
        assert sum(rep["states"].values()) == 8
        if "uncertain" not in rep["states"]:
            assert rep["rule_vs_fallback_uncertain"]["rows"] == 0
            assert rep["uncertain_rows"]["fallback_rule"] is None
    assert out["criteria"]["3_natural_split_changed_rows"] == 0
    assert out["conditions"]["B_press_own_background"]["all_rows_rule_vs_fallback"]["diff"] == 0
    for d in out["criteria"].values():
        if isinstance(d, dict) and d["rows"]:
            assert d["ci95"][0] <= d["diff"] <= d["ci95"][1]
    assert set(out["verdict"]) == {"1", "2", "3", "4"}
    assert all(isinstance(v, bool) for v in out["verdict"].values())
    # another unit of the same family, never the unit itself
    for sensor in (0, 7, 8, 23):
        other = script.other_unit(sensor)
        assert other != sensor and sensor_family(other) == sensor_family(sensor)
        assert other in family_sensors(sensor_family(sensor))


@pytest.mark.slow
def test_read_below_check_routes_as_the_gated_system_does(real_pipeline, monkeypatch, capsys):
    """scripts/why_read_below.py on 12 validation renders: every threshold of the grid, clean
    and mismatched touch; its row at the shipped `READ_BELOW` is the gated system's own answer
    (`TrustRouted` on the gated query's neighbours), and the rule picks the largest threshold
    within the allowance."""
    from ratouch.eval.answer import RA_TOUCH, answer_split, retrieve
    from ratouch.eval.judge import OfflineJudge
    from ratouch.model.gate import READ_BELOW
    from ratouch.world.splits import encode_test_split

    if real_pipeline.gate is None or real_pipeline.generator_reader is None:
        pytest.skip("no touch gate or reader in the shipped weights")
    script, out = _run_on_shipped("why_read_below", ["--n", "12"], real_pipeline, monkeypatch,
                                  capsys)
    assert set(out["touch"]) == {"clean", "mismatched"}
    for block in out["touch"].values():
        assert list(block["by_threshold"]) == [str(t) for t in script.GRID]
        counts = [r["reader_answers"] for r in block["by_threshold"].values()]
        assert counts == sorted(counts) and 0 <= counts[-1] <= 12
    split = encode_test_split(real_pipeline.encoders, indices=range(1_100_000, 1_100_012),
                              split="train")
    routed = answer_split(real_pipeline, split, RA_TOUCH,
                          ids=retrieve(real_pipeline, split.V, split.T, 5, "gated"),
                          generator=real_pipeline.system_generator("gated"),
                          judge=OfflineJudge()).scores
    assert out["touch"]["clean"]["by_threshold"][str(READ_BELOW)]["gated"] == \
        pytest.approx(routed.mean(), abs=1e-3)
    assert script.choose((0.1, 0.2, 0.3), {0.1: 0.0, 0.2: 0.04, 0.3: 0.06}, 0.05) == 0.2
    assert script.choose((0.1,), {0.1: 0.2}, 0.05) is None


def _run_on_shipped(name: str, argv: list[str], pipeline, monkeypatch, capsys):
    """Run script `name` with `argv` on the tests' real pipeline: (the script's module, the
    JSON object it printed last)."""
    script = _script(name)
    _Shipped.pipeline = pipeline
    monkeypatch.setattr(script, "RATouchPipeline", _Shipped)
    script.main(argv)
    return script, _last_json(capsys)


def _last_json(capsys) -> dict:
    """The JSON object a script prints last (after its progress lines)."""
    text = capsys.readouterr().out
    return json.loads(text[text.rindex("\n{") + 1:] if "\n{" in text else text)


def test_unfamiliar_contact_check_reads_every_measure(tmp_path, capsys):
    """scripts/why_unfamiliar_contact.py, small, on a calibration with a small colour-blind
    model: per family before and after on fresh views beyond the limit, no frame within the
    limit changed (the model never reads one), and Taxim's real frames' views; without the
    model it says so and exits."""
    from ratouch.model.trust import TrustCalibration
    from ratouch.paths import trust_calibration
    from ratouch.train.trust import validation_blanks, validation_presses, with_unfamiliar_contact

    shipped = TrustCalibration.load(trust_calibration("default-s"))
    cal = with_unfamiliar_contact(shipped, n=30, seed=8, val_presses=validation_presses(8, n=40),
                                  val_blanks=validation_blanks(8, n=40), n_validation=40)
    path = cal.save(tmp_path / "cal.json")
    script = _script("why_unfamiliar_contact")
    out_file = tmp_path / "out.json"
    script.main(["--after", str(path), "--n", "8", "--per-kind", "1", "--blanks", "4",
                 "--views", "1", "--test", "5", "--out", str(out_file)])
    out = json.loads(capsys.readouterr().out)
    assert json.loads(out_file.read_text()) == out
    assert out["threshold"] == cal.contact_unfamiliar[1]
    for side in ("before", "after"):
        assert set(out["fresh"][side]) == {"digit", "gelsight", "mini"}
        for r in out["fresh"][side].values():
            assert r["everyday_answered_minus_blanks_contact"] == pytest.approx(
                r["everyday_answered"] - r["drifted_blanks_contact"], abs=1e-3) or np.isnan(
                r["everyday_answered"])
    assert sum(out["fresh"]["counts"].values()) > 0
    for group in out["within_limit"].values():
        assert group["changed"] == 0
    assert out["within_limit"]["world test presses"]["frames"] == 5
    real = out["real_beyond"]
    for side in ("before", "after"):
        assert " of " in real[side]["taxim_press_views_refused"]
    with pytest.raises(SystemExit, match="no colour-blind contact model"):
        script.main(["--n", "2"])


@pytest.mark.slow
def test_geometry_encoder_check_trains_both_arms_and_reads_every_measure(real_pipeline,
                                                                         monkeypatch, capsys):
    """scripts/why_geometry_encoder.py, tiny: both towers trained a few steps on the same
    data, each read on fresh presses, world validation renders and Taxim's real presses; the
    geometry arm's paired gain with its CI, and the criteria as booleans."""
    script, out = _run_on_shipped(
        "why_geometry_encoder", ["--world", "16", "--fit", "1", "--eval", "1", "--world-eval",
                                 "8", "--steps", "3", "--batch", "16", "--seeds", "0",
                                 "--workers", "1"], real_pipeline, monkeypatch, capsys)
    families = {"digit", "gelsight", "mini"}
    assert set(out["arms"]) == {"difference_seed0", "geometry_seed0"}
    for row in out["arms"].values():
        for key in ("everyday_bg", "everyday_alone", "world_bg", "world_alone"):
            assert set(row[key]) == families | {"all"}
            assert all(v is None or 0 <= v <= 1 for v in row[key].values())
        assert set(row["distinct_top1_bg"]) == families
        assert row["real_presses"] == 72 and 0 <= row["real_read_hard"] <= 72
    for key, g in out["geometry_minus_difference"].items():
        assert g["ci95"][0] <= g["all"] <= g["ci95"][1], key
    assert set(out["criteria"]) == {"everyday_gain_at_least_0.03_ci_above_0",
                                    "world_no_family_down_more_than_0.02", "no_collapse",
                                    "height_map_helps"}
    assert out["criteria"]["height_map_helps"] == all(
        v for k, v in out["criteria"].items() if k != "height_map_helps")
    # the geometry arm reads three channels more; without a background they are zero
    assert out["config"]["input_size"] == [128, 96]
    assert script.GEOMETRY_CHANNELS == 3


def test_geometry_encoder_inputs_add_the_height_map_only_where_a_background_gave_one():
    """The geometry arm's three extra channels: the height map over its depth, the log depth
    over the family's reference and a flag; all zero for a frame read without a background."""
    script = _script("why_geometry_encoder")
    rng = np.random.default_rng(0)
    n, h, w = 3, 8, 6
    d = {"plain": rng.random((n, 4, h, w), np.float32),
         "with_bg": rng.random((n, 4, h, w), np.float32),
         "shape": rng.random((n, 1, h, w), np.float32),
         "has_height": np.array([True, True, False]),
         "log_depth": np.array([1.0, 2.0, 0.0], np.float32),
         "family": np.array(["digit", "mini", "digit"])}
    idx = np.arange(n)
    use_bg = np.array([True, False, True])
    plain = script._inputs(d, idx, use_bg, "difference", {"digit": 0.5, "mini": 1.0}).numpy()
    assert plain.shape == (n, 4, h, w)
    assert np.array_equal(plain[0], d["with_bg"][0]) and np.array_equal(plain[1], d["plain"][1])
    geo = script._inputs(d, idx, use_bg, "geometry", {"digit": 0.5, "mini": 1.0}).numpy()
    assert geo.shape == (n, 7, h, w)
    assert np.array_equal(geo[:, :4], plain)
    assert np.allclose(geo[0, 4], d["shape"][0, 0]) and np.allclose(geo[0, 5], 0.5)
    assert np.all(geo[0, 6] == 1)
    assert not geo[1, 4:].any()   # read without its background: no height map
    assert not geo[2, 4:].any()   # a background but no height map (no lookup)


@pytest.mark.skipif(not geometry_calibration().is_file(), reason="no geometry calibration")
def test_unfamiliar_floors_check_reads_every_family_and_the_real_frames(capsys):
    """scripts/why_unfamiliar_floors.py, small: per family the recoloured blank pairs and
    presses beyond the limit read before and after, the frames within the limit whose state
    changed, and recoloured views of Taxim's real presses."""
    script = _script("why_unfamiliar_floors")
    script.main(["--blanks", "6", "--per-kind", "1", "--views", "1", "--test", "6"])
    out = json.loads(capsys.readouterr().out)
    assert set(out["fresh"]) == {"digit", "gelsight", "mini"}
    for row in out["fresh"].values():
        assert 0 <= row["blank pairs"] <= 6 and 0 <= row["presses"] <= 8
        for side in ("before", "after"):
            assert set(row[side]) == {"blanks_contact", "blanks_contact_or_uncertain",
                                      "presses_answered", "presses_contact"}
    within = out["within_limit"]
    assert within["Taxim's real presses"]["pairs"] == 72
    assert within["fresh pairs, not recoloured"]["changed"] == 0  # nothing within the limit moves
    assert 0 < out["real"]["taxim press views beyond the limit"] <= 72


def test_unfamiliar_alone_check_reads_every_family_and_the_real_frames(capsys):
    """scripts/why_unfamiliar_alone.py, small: per family the recoloured frames beyond the
    limit read alone, the disc-press model's decision against the state given; frames within
    the limit unchanged; recoloured views of Taxim's presses."""
    script = _script("why_unfamiliar_alone")
    script.main(["--test", "12", "--per-kind", "1", "--blanks", "4", "--views", "1"])
    out = json.loads(capsys.readouterr().out)
    assert set(out["fresh"]) == {"digit", "gelsight", "mini"}
    for row in out["fresh"].values():
        assert set(row) == {"world presses", "world blanks", "everyday presses",
                            "drifted blanks"}
        for rec in row.values():
            if rec["views"]:
                # "no contact" is the same before and after: only "contact" may turn uncertain
                assert rec["before"]["no contact"] == rec["after"]["no contact"]
                assert rec["after"]["contact"] == 0
    for rec in out["within_limit"].values():
        assert rec["changed"] == 0
    assert out["within_limit"]["Taxim's real frames"]["frames"] == 74
    assert out["real"]["after"]["contact"] in (0, None)


@pytest.mark.slow
def test_routed_reading_check_compares_the_readings(real_pipeline, monkeypatch, capsys):
    """scripts/why_routed_reading.py, small: the routed, the paper's tactile and the adapted
    readings of everyday presses and world renders per family, with the background and
    alone, Taxim's real presses, and every reading the one its router names."""
    _, out = _run_on_shipped("why_routed_reading", [
        "--per-kind", "1", "--world-start", "2600000", "--world", "6", "--taxim", "2"],
        real_pipeline, monkeypatch, capsys)
    for way in ("with_background", "alone"):
        assert set(out["everyday"][way]) == {"digit", "gelsight", "mini", "all"}
        assert set(out["world"][way]) <= {"digit", "gelsight", "mini", "all"}
        assert out["world"][way]["all"]["rows"] == 6
        alll = out["everyday"][way]["all"]
        assert alll["rows"] == 3 * 7 and set(alll) >= {"routed", "tactile", "adapted"}
        assert 0 <= alll["routed_to_adapted"] <= 1
        lo, hi = alll["routed_minus_tactile"]["ci95"]
        assert lo <= alll["routed_minus_tactile"]["mean"] <= hi
        real = out["real"][way]
        assert sum(real["routed"].values()) == real["answered"] <= out["real"]["presses"] == 4
    assert out["off_router"] == 0
