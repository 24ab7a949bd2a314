"""The touch gate (`ratouch.model.gate`), its trainer, the gated query mode and the retrieval
system a request names."""

from __future__ import annotations

import json

import numpy as np
import pytest

from conftest import HAVE_ASSETS
from ratouch.cli import main
from ratouch.errors import ConfigError, DataError, DataNotFoundError
from ratouch.model.gate import FEATURES, TouchGate, fit_logistic, gate_features, mix
from ratouch.model.trust import Novelty
from ratouch.search.modes import QUERY_MODES, RETRIEVAL_SYSTEMS, WITHHOLDING_SYSTEMS
from ratouch.serve.request import QueryRequest


def _novelty(dim: int, threshold: float = 1.5) -> Novelty:
    return Novelty(np.zeros(dim), np.eye(dim)[:2], np.ones(2), 1.0, threshold)


def _unit(x):
    return x / np.linalg.norm(x, axis=1, keepdims=True)


def test_mix_ends_are_the_two_queries():
    rng = np.random.default_rng(0)
    V, J = rng.normal(size=(3, 8)), rng.normal(size=(3, 8))
    assert np.allclose(mix(V, J, np.ones(3)), _unit(J), atol=1e-6)
    assert np.allclose(mix(V, J, np.zeros(3)), _unit(V), atol=1e-6)
    half = mix(V, J, np.full(3, 0.5))
    assert np.allclose(np.linalg.norm(half, axis=1), 1, atol=1e-6)
    assert np.allclose(half, _unit(_unit(V) + _unit(J)), atol=1e-6)


def test_rule_gate_turns_touch_off_where_it_is_novel():
    nov = _novelty(4)
    gate = TouchGate("rule").with_novelty(nov, nov)
    V = np.ones((2, 4)) * 0.1
    T = np.array([[0.1, 0.1, 0.1, 0.1], [9.0, 9.0, 9.0, 9.0]])  # familiar, far from the mean
    w = gate.weights(V, T, V)
    assert w.tolist() == [1.0, 0.0]
    q, w2 = gate.query(V, T, np.array([[0, 0, 0, 1.0], [0, 0, 0, 1.0]]))
    assert np.allclose(q[0], [0, 0, 0, 1.0]) and np.allclose(q[1], _unit(V)[1], atol=1e-6)
    why = gate.explain(V[1:], T[1:], V[1:])
    assert why["touch_weight"] == 0.0 and "unlike the training renders" in why["why"][0]


def test_gate_needs_its_novelty_models():
    with pytest.raises(ConfigError, match="novelty"):
        TouchGate("rule").weights(np.ones((1, 4)), np.ones((1, 4)), np.ones((1, 4)))
    with pytest.raises(ConfigError, match="kind"):
        TouchGate("always")


def test_logistic_fit_finds_the_separating_direction():
    rng = np.random.default_rng(1)
    X = rng.normal(size=(400, 3))
    y = (X[:, 1] - 0.5 * X[:, 2] > 0).astype(float)
    mean, scale, coef, b = fit_logistic(X, y)
    p = 1 / (1 + np.exp(-(((X - mean) / scale) @ coef + b)))
    assert ((p > 0.5) == (y > 0.5)).mean() > 0.95
    assert coef[1] > 0 > coef[2] and abs(coef[0]) < abs(coef[1]) / 3
    # weights: samples of weight 0 do not count
    w = np.ones(400)
    w[:200] = 0
    y2 = y.copy()
    y2[:200] = 1 - y2[:200]          # flipped labels, weight 0
    _, _, coef2, _ = fit_logistic(X, y2, w)
    assert coef2[1] > 0


def test_gate_file_round_trip_and_bad_files(tmp_path):
    nov = _novelty(4)
    gate = TouchGate("learnt", np.arange(5.0), np.ones(5), np.array([1.0, -1, 0.5, 0, 2]), -0.3,
                     report={"pairs": 10})
    path = tmp_path / "g.json"
    gate.save(path)
    back = TouchGate.load(path).with_novelty(nov, nov)
    rng = np.random.default_rng(2)
    V, T, J = (rng.normal(size=(4, 4)) for _ in range(3))
    assert np.allclose(back.weights(V, T, J), gate.with_novelty(nov, nov).weights(V, T, J))
    assert back.report == {"pairs": 10}
    assert gate_features(V, T, J, nov, nov).shape == (4, len(FEATURES))
    with pytest.raises(DataNotFoundError, match="ratouch train gate"):
        TouchGate.load(tmp_path / "missing.json")
    path.write_bytes(b"\xff\xfe not json")
    with pytest.raises(DataError, match="not a touch gate"):
        TouchGate.load(path)
    path.write_text(json.dumps({**gate.to_dict(), "features": ["x"]}))
    with pytest.raises(DataError, match="not a touch gate"):
        TouchGate.load(path)


def test_the_gated_mode_and_the_retrieval_systems():
    assert "gated" in QUERY_MODES and QUERY_MODES["gated"].needs_touch
    assert set(RETRIEVAL_SYSTEMS) == {"paper", "gated", "text", "fallback"}
    assert RETRIEVAL_SYSTEMS["text"] == RETRIEVAL_SYSTEMS["paper"] == \
        RETRIEVAL_SYSTEMS["fallback"] == "joint"
    assert WITHHOLDING_SYSTEMS == {"gated", "fallback"}
    calls = []

    def joint(V, T, gated=False):
        calls.append(gated)
        return V + T

    V, T = np.ones((2, 3), np.float32), np.ones((2, 3), np.float32)
    QUERY_MODES["gated"].vectors(V, T, joint)
    QUERY_MODES["joint"].vectors(V, T, joint)
    assert calls == [True, False]
    with pytest.raises(ConfigError, match="unknown retrieval system 'best'"):
        QueryRequest.decode(np.zeros((32, 32, 3), np.uint8), retrieval="best")
    assert QueryRequest.decode(np.zeros((32, 32, 3), np.uint8), retrieval="gated").retrieval \
        == "gated"


def test_train_gate_rejects_too_few_pairs(capsys):
    assert main(["train", "gate", "--n", "5"]) == 2
    assert "at least 20" in capsys.readouterr().err


@pytest.mark.slow
def test_real_pipeline_reads_the_system_the_request_names(real_pipeline, world):
    """With the shipped gate: a request naming "gated" has RA-Touch read the gated query's
    neighbours, "paper" the joint query's; the result says which and how far touch steered;
    touch that is pure noise is trusted less than the pair's own touch."""
    s = world.sample("test", 40)
    out = {}
    for system in RETRIEVAL_SYSTEMS:
        req = QueryRequest.decode(s.visual, s.tactile, s.box, 5, retrieval=system)
        out[system] = real_pipeline.answer([req])[0].to_dict()
    for system, res in out.items():
        r = res["retrieval"]
        assert r["system"] == system and r["reads"] == RETRIEVAL_SYSTEMS[system]
        assert 0 <= r["touch_weight"] <= 1 and r["why"]
        assert set(res["neighbours"]) >= {"joint", "gated"}
    assert out["paper"]["retrieval"]["touch_weight"] == out["gated"]["retrieval"]["touch_weight"]
    noise = np.random.default_rng(0).integers(0, 256, s.tactile.shape, dtype=np.uint8)
    noisy = real_pipeline.answer([QueryRequest.decode(s.visual, noise, s.box, 5,
                                                      retrieval="gated")])[0].to_dict()
    if real_pipeline.gate is not None:
        assert noisy["retrieval"]["kind"] == "learnt"
        assert noisy["retrieval"]["touch_weight"] < out["gated"]["retrieval"]["touch_weight"]
    image_only = real_pipeline.answer([QueryRequest.decode(s.visual, None, s.box, 5)])[0]
    assert image_only.retrieval is None


@pytest.mark.slow
def test_the_gated_system_withholds_an_unfamiliar_sensors_touch(real_pipeline, world):
    """docs/premise.md, "Touch withheld only beyond every validation render": a frame beyond
    every rendered unit (a pair's own frame, its colours inverted): with the rule on, the
    gated system reads the image query's neighbours with a neutral touch (touch weight 0,
    kind "withheld", and why) and the paper's system reads it as before; with the rule off
    the gate weighs it."""
    from ratouch.world.sensors import WITHHOLD_LIMIT, guess_family

    s = world.sample("test", 40)
    odd = 255 - s.tactile
    assert guess_family(odd)[1] > WITHHOLD_LIMIT >= guess_family(s.tactile)[1]

    def ask(system):
        return QueryRequest.decode(s.visual, odd, s.box, 5, retrieval=system)

    shipped = real_pipeline.withhold_unfamiliar
    real_pipeline.withhold_unfamiliar = False
    try:
        off = real_pipeline.answer([ask("gated")])[0].to_dict()["retrieval"]
        real_pipeline.withhold_unfamiliar = True
        g = real_pipeline.answer([ask("gated")])[0].to_dict()
        again = real_pipeline.regenerate(ask("gated"),
                                         [n["id"] for n in g["neighbours"]["image"]])
        paper = real_pipeline.answer([ask("paper")])[0].to_dict()["retrieval"]
    finally:
        real_pipeline.withhold_unfamiliar = shipped
    assert off["reads"] == "gated" and off["kind"] != "withheld"
    r = g["retrieval"]
    assert (r["kind"], r["touch_weight"], r["reads"]) == ("withheld", 0.0, "image")
    assert "looks like none of the sensors" in r["why"][0]
    from ratouch.model.gate import WITHHOLD_COST
    assert f"{WITHHOLD_COST['gated']:.2f} below the paper's system" in r["why"][0]
    # the gated query gives the withheld touch no say: it is the image query, and the page's
    # gated gallery shows the neighbours the answer read
    assert [n["id"] for n in g["neighbours"]["gated"]] == \
        [n["id"] for n in g["neighbours"]["image"]]
    queries = {p["role"]: (p["x"], p["y"]) for p in g["pca"]["points"]
               if p["role"] in ("query_gated", "query_image")}
    assert len(queries) == 2 and queries["query_gated"] == queries["query_image"]
    assert r["generator"] == ("reader" if real_pipeline.generator_reader is not None
                              else "paper")
    # the answer is the chosen generator's from the image neighbours and the neutral touch
    assert again["description"]["ra_touch"] == g["description"]["ra_touch"]
    assert g["description"]["baseline"]  # the baseline still reads the frame
    assert paper["reads"] == "joint" and paper["kind"] != "withheld"


@pytest.mark.slow
def test_the_fallback_system_is_the_papers_unless_the_sensor_is_unlike_every_unit(
        real_pipeline, world):
    """docs/premise.md, "The paper's system, falling back to vision": for a frame that looks
    like a rendered unit (with and without its background) `fallback` answers exactly as
    `paper` does and says why touch was not withheld; for a frame beyond every rendered unit
    it answers as the withholding rule does in `gated` (the image query's neighbours, the
    same generator and neutral touch, so the same words), while `paper` reads its touch; with
    the rule off it is `paper` again."""
    from ratouch.world.sensors import WITHHOLD_LIMIT

    s = world.sample("test", 40)
    for bg in (None, world.background_image(s.sensor)):
        got = {system: real_pipeline.answer([QueryRequest.decode(
            s.visual, s.tactile, s.box, 5, background=bg, retrieval=system)])[0].to_dict()
            for system in ("paper", "fallback")}
        assert got["fallback"]["description"] == got["paper"]["description"]
        assert got["fallback"]["neighbours"] == got["paper"]["neighbours"]
        r = got["fallback"]["retrieval"]
        assert (r["system"], r["reads"], r["generator"]) == ("fallback", "joint", "paper")
        assert r["kind"] != "withheld" and "touch is not withheld" in " ".join(r["why"])
        assert f"{WITHHOLD_LIMIT:.2f}" in " ".join(r["why"])
    odd = 255 - s.tactile  # beyond every rendered unit (the test above checks it)

    def ask(system):
        return real_pipeline.answer([QueryRequest.decode(s.visual, odd, s.box, 5,
                                                         retrieval=system)])[0].to_dict()

    shipped = real_pipeline.withhold_unfamiliar
    try:
        real_pipeline.withhold_unfamiliar = True
        fb, g, paper = ask("fallback"), ask("gated"), ask("paper")
        real_pipeline.withhold_unfamiliar = False
        off = ask("fallback")
    finally:
        real_pipeline.withhold_unfamiliar = shipped
    r = fb["retrieval"]
    assert (r["kind"], r["touch_weight"], r["reads"]) == ("withheld", 0.0, "image")
    from ratouch.model.gate import WITHHOLD_COST
    assert f"{WITHHOLD_COST['fallback']:.2f} below the paper's system" in r["why"][0]
    assert "choose the `paper` system" in r["why"][-1]
    assert r["generator"] == g["retrieval"]["generator"]
    assert fb["description"]["ra_touch"] == g["description"]["ra_touch"]
    assert paper["retrieval"]["reads"] == "joint" and paper["retrieval"]["kind"] != "withheld"
    assert off["retrieval"]["reads"] == "joint" and off["description"] == paper["description"]


def _other_unit(sensor: int) -> int:
    """The next unit of `sensor`'s family (scripts/why_withhold_uncertain.py's choice)."""
    from ratouch.world.sensors import family_sensors, sensor_family

    units = list(family_sensors(sensor_family(sensor)))
    return units[(units.index(int(sensor)) + 1) % len(units)]


@pytest.mark.slow
def test_touch_in_doubt_is_withheld_by_the_withholding_systems_only(real_pipeline):
    """docs/premise.md, "Touch withheld where contact against the background is uncertain and
    the frame alone shows none": a blank render (test pair 2 without contact) against another
    unit's background reads "uncertain", and alone "no contact": `fallback` and `gated` answer
    from the image query's neighbours with a neutral touch and say why (quoting
    `DOUBT_EFFECT`), `regenerate` agrees, `paper` reads its touch; a press against another
    unit's background that reads "uncertain" but "contact" alone (test pair 4) keeps its touch
    in `fallback`, which answers it exactly as `paper`."""
    from ratouch.model.gate import DOUBT_EFFECT
    from ratouch.world.config import WorldConfig
    from ratouch.world.sampler import World

    blanks, presses = World(WorldConfig().with_stress(no_contact=1.0)), World(WorldConfig())
    s = blanks.sample("test", 2)
    bg = blanks.background_image(_other_unit(s.sensor))

    def ask(sample, back, system):
        return QueryRequest.decode(sample.visual, sample.tactile, sample.box, 5, background=back,
                                   retrieval=system)

    got = {system: real_pipeline.answer([ask(s, bg, system)])[0].to_dict()
           for system in ("fallback", "gated", "paper")}
    t = got["paper"]["trust"]["tactile"]
    assert t["state"] == "uncertain" and t["alone"]["state"] == "no contact"
    for system in ("fallback", "gated"):
        r = got[system]["retrieval"]
        assert (r["kind"], r["touch_weight"], r["reads"]) == ("withheld", 0.0, "image")
        assert "the frame read alone shows no contact" in r["why"][0]
        assert f"{DOUBT_EFFECT[system]['blanks']:+.2f} where the frame was a blank" in r["why"][0]
        assert [n["id"] for n in got[system]["neighbours"]["gated"]] == \
            [n["id"] for n in got[system]["neighbours"]["image"]]
    assert got["fallback"]["description"]["ra_touch"] == got["gated"]["description"]["ra_touch"]
    again = real_pipeline.regenerate(ask(s, bg, "fallback"),
                                     [n["id"] for n in got["fallback"]["neighbours"]["image"]])
    assert again["description"]["ra_touch"] == got["fallback"]["description"]["ra_touch"]
    assert got["paper"]["retrieval"]["reads"] == "joint"
    assert got["paper"]["retrieval"]["kind"] != "withheld"

    p = presses.sample("test", 4)
    pbg = presses.background_image(_other_unit(p.sensor))
    kept = {system: real_pipeline.answer([ask(p, pbg, system)])[0].to_dict()
            for system in ("fallback", "paper")}
    t = kept["fallback"]["trust"]["tactile"]
    assert t["state"] == "uncertain" and t["alone"]["state"] == "contact"
    assert kept["fallback"]["retrieval"]["reads"] == "joint"
    assert kept["fallback"]["description"] == kept["paper"]["description"]
    assert kept["fallback"]["neighbours"] == kept["paper"]["neighbours"]
    # without a background nothing is doubted: the frame alone is the only reading
    alone = real_pipeline.answer([ask(s, None, "fallback")])[0].to_dict()
    assert "alone" not in alone["trust"]["tactile"]


def test_doubts_touch_reads_the_second_opinion():
    """`doubts_touch`: only a block uncertain against its background whose frame alone is not
    "contact"."""
    from ratouch.model.trust import doubts_touch

    assert not doubts_touch(None) and not doubts_touch({"state": "uncertain"})
    for alone, doubted in (("no contact", True), ("uncertain", True), ("contact", False)):
        assert doubts_touch({"state": "uncertain", "alone": {"state": alone, "contact": 0.1}}) \
            is doubted
    assert not doubts_touch({"state": "contact", "alone": {"state": "no contact"}})


def test_the_doubt_effect_quoted_is_the_measured_one():
    """"What retrieval did" quotes `DOUBT_EFFECT` where touch in doubt is withheld: per
    withholding system, the rule's effect on blanks and presses read uncertain, as
    scripts/why_withhold_uncertain.py measured it last on fresh probe rows."""
    import json

    from ratouch.model.gate import DOUBT_EFFECT
    from ratouch.paths import REPO

    assert set(DOUBT_EFFECT) == WITHHOLDING_SYSTEMS
    d = json.loads((REPO / "docs" / "premise-result-withhold-second-opinion.json").read_text())
    assert d["config"]["rule"] == "second-opinion" and d["config"]["split"] == "probe"
    rule = d["rules"]["second-opinion"]
    for key, block in (("blanks", "1_blanks_uncertain"), ("presses", "2_presses_uncertain")):
        assert DOUBT_EFFECT["fallback"][key] == round(rule["criteria"][block]["diff"], 2)
    for key, block in (("blanks", "blanks_uncertain"), ("presses", "presses_uncertain")):
        assert DOUBT_EFFECT["gated"][key] == round(rule["gated"][block]["diff"], 2)


@pytest.mark.slow
def test_a_look_checks_false_alarm_keeps_its_touch(real_pipeline, world):
    """A world DIGIT frame beyond the look check's caution limit (test pair 13, one of its six
    false alarms on the test split) but within every rendered unit's: the trust line still
    cautions, and the gated system still reads its touch, rule on or off."""
    from ratouch.world.sensors import LOOK_LIMIT, WITHHOLD_LIMIT, guess_family

    s = world.sample("test", 13)
    assert LOOK_LIMIT < guess_family(s.tactile)[1] <= WITHHOLD_LIMIT
    shipped = real_pipeline.withhold_unfamiliar
    real_pipeline.withhold_unfamiliar = True
    try:
        out = real_pipeline.answer([QueryRequest.decode(s.visual, s.tactile, s.box, 5,
                                                        retrieval="gated")])[0].to_dict()
    finally:
        real_pipeline.withhold_unfamiliar = shipped
    assert out["retrieval"]["kind"] != "withheld" and out["retrieval"]["reads"] == "gated"
    assert out["trust"]["tactile"]["unfamiliar_sensor"] is True


@pytest.mark.slow
@pytest.mark.skipif(not HAVE_ASSETS, reason="the trained weights are not in assets/")
def test_fit_gate_on_a_few_probe_pairs(real_pipeline):
    """The trainer end to end on 40 pairs: a learnt gate and a held-out table per variant."""
    from ratouch.train.gate import VARIANTS, fit_gate, format_gate_report

    gate = fit_gate(real_pipeline, real_pipeline.trust, n=40, seed=3, scarce=("cotton",))
    assert gate.kind == "learnt" and np.isfinite(gate.coef).all()
    assert set(gate.report["by_variant"]) == set(VARIANTS)
    row = gate.report["by_variant"]["clean"]["all"]
    assert row["n"] == 20 and all(0 <= row[m] <= 1 for m in ("paper", "image", "rule", "learnt"))
    assert "mismatched" in format_gate_report(gate.report)


def test_the_withholding_cost_quoted_is_the_measured_one():
    """"What retrieval did" quotes `WITHHOLD_COST` where touch is withheld: per withholding
    system, the cost measured last by scripts/why_withhold.py (`gated`:
    docs/premise-result-withhold.json, `fallback`: docs/premise-result-fallback.json)."""
    import json

    from ratouch.model.gate import WITHHOLD_COST
    from ratouch.paths import REPO

    assert set(WITHHOLD_COST) == WITHHOLDING_SYSTEMS
    for system, name in (("gated", "withhold"), ("fallback", "fallback")):
        measured = json.loads((REPO / "docs" / f"premise-result-{name}.json").read_text())
        assert measured["config"].get("system", "gated") == system
        assert WITHHOLD_COST[system] == \
            round(-measured["recoloured"]["rule_vs_paper"]["diff"], 2)
