"""Tests for ratouch.eval.judge: score parsing, the offline judge and its held-out validation against
GPT-4, judge_results, the `ratouch judge` CLI and the LLM judge against a local HTTP server."""

from __future__ import annotations

import json

import numpy as np
import pytest

from conftest import FakeLLM, serve_fake_llm
from ratouch.cli import main
from ratouch.errors import ConfigError, DataError
from ratouch.eval import judge as J
from ratouch.vocabulary import adjective_f1, parse_adjectives

KEY_ENV = "RATOUCH_TEST_JUDGE_KEY"
HAVE_DATA = all((J.judge_data_dir() / f"{m}.json").is_file() for m in J.MODELS)
needs_data = pytest.mark.skipif(not HAVE_DATA, reason=f"TVL judge data not found at "
                                                      f"{J.judge_data_dir()} (${J.DATA_DIR_ENV})")

HAND_MADE = [  # a file the judge has never seen: absolute paths, one failed generation
    {"image_fp": "/data/tvl/ssvtp/images_rgb/image_1_rgb.jpg", "label": "soft, plush, fabric",
     "generated response": "Soft, plush and woven.", "evaluation": "8\nClose match."},
    {"image_fp": "/data/tvl/hct/data1/x/vision/1.jpg", "label": "hard, smooth, glossy",
     "generated response": "rough, matte, soft.", "evaluation": "2\nOpposite."},
    {"image_fp": "/data/tvl/hct/data1/x/vision/2.jpg", "label": "uneven, bumpy",
     "generated response": None, "evaluation": "garbled"},
]


# --------------------------------------------------------------------------- parsing


@pytest.mark.parametrize("text, expected", [
    ("7\nThe assistant's response ...", 7.0),
    ("7.5\nThe assistant ...", 7.5),
    ("7.785 The response", 7.785),
    ("10\n", 10.0),
    ("1", 1.0),
    ("  8 \n\nExplanation", 8.0),
    ("Score: 6/10\nok", 6.0),
    ("**9**\nvery close", 9.0),
    ("0\nnothing", None),
    ("11\ntoo high", None),
    ("10.5", None),
    ("2023 was a year", None),
    ("The assistant deserves 7", None),
    ("", None),
    (None, None),
])
def test_parse_gpt_score(text, expected):
    assert J.parse_gpt_score(text) == expected


@pytest.mark.parametrize("text, expected", [
    ("hard, smooth, flat, splotchy.", ["hard", "smooth", "flat", "splotchy"]),
    ("Soft, plush and cushioned.", ["soft", "plush", "cushioned"]),
    ("slightly squishy, very soft", ["squishy", "soft"]),
    ("cushioned., cushioned.", ["cushioned"]),
    ("'smooth'/sleek; cloth-like", ["smooth", "sleek", "cloth-like"]),
    (None, []),
    ("  . ", []),
])
def test_adjectives(text, expected):
    assert parse_adjectives(text) == expected


# --------------------------------------------------------------------------- offline judge


def test_offline_judge_is_monotonic():
    j = J.OfflineJudge()
    for label, exact, synonyms, antonyms in [
        ("soft, plush, fabric", "soft, plush, fabric", "cushioned, squishy, woven",
         "hard, rigid, stiff"),
        ("smooth, glossy, hard", "hard, smooth, glossy.", "sleek, polished, rigid",
         "rough, matte, soft"),
    ]:
        s_exact, s_syn, s_ant = (j.score(label, r) for r in (exact, synonyms, antonyms))
        assert s_exact >= 8.5
        assert 4.0 < s_syn < s_exact
        assert s_ant <= 2.5 < s_syn
    partial = j.score("soft, plush, fabric", "soft, hard, metallic")
    assert j.score("soft, plush, fabric", "hard, rigid, stiff") < partial < j.score(
        "soft, plush, fabric", "soft, plush, fabric")


def test_offline_judge_range_and_failed_responses():
    j = J.OfflineJudge()
    assert j.score("hard, smooth", None) == 1.0
    assert j.score("hard, smooth", "  ") == 1.0
    for resp in ("cool, reflective, warm", "hard", "a, b, c, d, e, f", "smooth, smooth"):
        assert 1.0 <= j.score("hard, smooth", resp) <= 10.0
    e = j.explain("hard, smooth", "rigid, sleek, cool")
    assert e["predicted"] == ["rigid", "sleek", "cool"]
    assert set(e["features"]) == set(J.FEATURES)
    assert e["features"]["non_tactile_share"] == pytest.approx(1 / 3)
    rates = J.answer_rates(["hard", None])
    assert j.score_many([("hard", "hard"), ("hard", None)]) == [j.score("hard", "hard", rates), 1.0]
    with pytest.raises(DataError):
        j.score("", "hard")


def test_similarity_and_antonyms():
    assert J.similarity("soft", "soft") == 1.0
    assert 0 < J.similarity("soft", "plush") < 1
    assert J.similarity("soft", "hard") == 0.0
    assert J.antonymy("soft", "hard") == 1.0 and J.antonymy("smooth", "rough") == 1.0
    assert J.antonymy("flexible", "rigid") == 1.0 and J.antonymy("soft", "plush") == 0.0
    assert adjective_f1("hard, smooth", "hard, rigid") == pytest.approx(0.5)


@pytest.mark.parametrize("params, fragment", [
    ({"features": ["x"], "mean": [0], "scale": [1], "intercept": 0, "weights": [1],
      "label_rates": {}}, "features"),
    ({"features": list(J.FEATURES)}, "lacks"),
    ({"features": list(J.FEATURES), "mean": [0] * 5, "scale": [0] * 5, "intercept": 0,
      "weights": [1] * 5, "label_rates": {}}, "scale"),
    ({"features": list(J.FEATURES), "mean": [0] * 4, "scale": [1] * 5, "intercept": 0,
      "weights": [1] * 5, "label_rates": {}}, "mean"),
    ({"features": list(J.FEATURES), "mean": [0] * 5, "scale": [1] * 5, "intercept": 0,
      "weights": [1] * 5, "label_rates": {"soft": 1.5}}, "label_rates"),
    ({"features": list(J.FEATURES), "mean": [0] * 5, "scale": [1] * 5, "intercept": 0,
      "weights": [1] * 5}, "lacks"),
])
def test_offline_judge_rejects_bad_calibration(params, fragment):
    with pytest.raises(ConfigError, match=fragment):
        J.OfflineJudge(params)


# --------------------------------------------------------------------------- protocol


@needs_data
def test_split_is_by_sample_stratified_and_disjoint():
    data = J.load_tvl_results()
    recs = data[J.MODELS[0]]
    fit, held = J.heldout_split(recs, seed=0)
    assert not set(fit) & set(held) and sorted(fit + held) == list(range(len(recs)))
    assert sum(J.subset_of(recs[i]["image_fp"]) == "SSVTP" for i in fit) == 23
    assert sum(J.subset_of(recs[i]["image_fp"]) == "HCT" for i in fit) == 178
    assert J.heldout_split(recs, seed=0) == (fit, held)
    assert J.heldout_split(recs, seed=1) != (fit, held)


@needs_data
def test_heldout_validation_meets_the_target():
    r = J.validate_judge()
    assert (r["n_heldout_samples"], r["n_heldout_answers"], r["n_fit_samples"]) == (201, 603, 201)
    assert r["spearman_offline"] >= 0.85
    assert r["spearman_offline"] > r["spearman_f1"] + 0.05
    assert r["ranking_identical"] and r["ranking_offline"] == r["ranking_gpt4"]
    text = J.format_validation(r)
    assert "Spearman" in text and "(identical)" in text and "leave one system out" in text


@needs_data
def test_a_system_never_fitted_on_is_ranked_and_scored_as_gpt4_does():
    lo = J.validate_judge()["loso"]
    assert set(lo["per_system"]) == set(J.MODELS)
    for s in lo["per_system"].values():
        assert s["n_answers"] == 201 and abs(s["error"]) <= J.TARGETS["max_abs_mean_error"]
    assert lo["ranking_identical"] and lo["ranking_offline"] == lo["ranking_gpt4"]
    assert lo["pooled_spearman"] >= J.TARGETS["pooled_spearman"]


@needs_data
def test_style_shifts_move_the_score_the_way_gpt4_would():
    r = J.validate_judge()
    sh = r["style_shifts"]
    assert set(sh["shifts"]) == set(J.SHIFTS)
    assert all(s["as_expected"] for s in sh["shifts"].values()), sh["shifts"]
    assert sh["shifts"]["pad"]["mean"] <= sh["original"]
    assert sh["shifts"]["antonyms"]["mean"] < sh["shifts"]["shuffle"]["mean"]
    le = r["length_effect"]
    assert abs(le["difference_per_adjective"]) <= J.TARGETS["length_effect_difference"]


@needs_data
def test_unweighted_matching_is_fooled_by_padding(monkeypatch):
    """The check can fail: with every word at full weight, generic padding raises the score."""
    data = J.load_tvl_results()
    fit, held = J.heldout_split(data[J.MODELS[0]])
    # `word_table` (in the features module) looks the weight up there
    monkeypatch.setattr(J.features, "informativeness", lambda word, label_rates, rates: 1.0)
    judge = J.OfflineJudge(J.fit_calibration(data, J.MODELS, fit))
    sh = J.style_shifts(data, held, judge)
    assert sh["shifts"]["pad"]["change"] > 0.1 and not sh["shifts"]["pad"]["as_expected"]


@needs_data
def test_refit_reproduces_the_shipped_calibration(tmp_path):
    params = J.fit_offline_judge()
    shipped = J.load_offline_config()
    assert params["fit"] == shipped["fit"] and params["label_rates"] == shipped["label_rates"]
    for key in ("mean", "scale", "weights"):
        np.testing.assert_allclose(params[key], shipped[key], rtol=1e-4, atol=1e-4)
    assert params["intercept"] == pytest.approx(shipped["intercept"], abs=1e-4)
    path = J.write_offline_config(params, tmp_path / "j.json")
    assert J.OfflineJudge(J.load_offline_config(path)).score("hard", "hard") == pytest.approx(
        J.OfflineJudge().score("hard", "hard"), abs=1e-3)


# --------------------------------------------------------------------------- informativeness


def test_a_word_said_for_every_sample_earns_nothing():
    j = J.OfflineJudge()
    labels = ["soft, plush", "hard, smooth", "rough, coarse", "soft, woven"] * 100
    plain = ["soft, plush", "hard, rigid", "coarse, gritty", "woven, fabric"] * 100
    padded = [a + ", textured, flexible" for a in plain]
    assert np.mean(j.score_many(zip(labels, padded))) <= np.mean(j.score_many(zip(labels, plain)))
    rates = J.answer_rates(padded)
    e = j.explain("rough, textured", padded[2], rates)
    status = {t["word"]: t for t in e["words"]}
    assert status["textured"]["status"] == "ignored" and status["textured"]["weight"] == 0.0
    assert status["coarse"]["status"] == "matched" and status["coarse"]["weight"] > 0.5
    # one answer alone: the system rate cannot be measured, nothing is ignored for it
    assert J.informativeness("textured", j.label_rates, J.answer_rates(["textured"])) > 0.5


def test_label_generic_words_earn_less_than_specific_ones():
    j = J.OfflineJudge()
    assert j.label_rates["uneven"] > j.label_rates["perforated"]
    assert (J.informativeness("uneven", j.label_rates, J.NO_RATES)
            < J.informativeness("perforated", j.label_rates, J.NO_RATES))
    rates = J.label_fit_rates(["soft, plush", "soft, fabric"])
    assert rates["soft"] == 1.0 and 0 < rates["plush"] < 1 and rates["metallic"] == 0.0
    with pytest.raises(DataError):
        J.label_fit_rates(["", "  "])


def test_a_contradicted_word_costs():
    j = J.OfflineJudge()
    assert j.score("soft, plush", "soft, plush, hard") < j.score("soft, plush", "soft, plush")
    e = j.explain("soft, plush", "soft, hard")
    assert [t["status"] for t in e["words"]] == ["matched", "clash"]


def test_style_shift_rewrites():
    labels, answers = ["soft, plush", "hard, smooth"], ["soft, woven", "rigid"]
    assert J.style_shift("pad", labels, answers, pad=["textured", "soft"]) == [
        "soft, woven, textured", "rigid, textured, soft"]
    assert J.style_shift("truncate", labels, answers) == ["soft", "rigid"]
    assert sorted(J.style_shift("shuffle", labels, answers, seed=3)) == sorted(answers)
    anti = J.style_shift("antonyms", labels, answers)
    assert "hard" in anti[0] and "soft" in anti[1] and "rough" in anti[1]
    assert J.antonym_answer("lined, dotted") is not None and J.antonym_answer("thick") == "thin"
    with pytest.raises(ConfigError):
        J.style_shift("reverse", labels, answers)


# --------------------------------------------------------------------------- bootstrap CI


def test_mean_ci_is_seeded_and_covers_the_mean():
    rng = np.random.default_rng(0)
    small, large = rng.normal(5, 2, 40), rng.normal(5, 2, 4000)
    m, lo, hi = J.mean_ci(small)
    assert lo < m < hi and J.mean_ci(small) == (m, lo, hi)
    assert J.mean_ci(small, seed=1) != (m, lo, hi)
    _, lo2, hi2 = J.mean_ci(large)
    assert hi2 - lo2 < (hi - lo) / 4
    assert J.mean_ci([3.0, 3.0]) == (3.0, 3.0, 3.0)
    with pytest.raises(DataError):
        J.mean_ci([])
    s = J.score_stats(["soft, plush", "hard"], ["soft", None], [8.0, 1.0])
    assert s["f1"] == pytest.approx((2 / 3 + 0) / 2) and s["mean_length"] == 0.5
    assert "[" in J.format_stats(s) and "F1 0.333" in J.format_stats(s)


# --------------------------------------------------------------------------- judge_results


def test_judge_results_counts_failed_and_subsets():
    out, summary = J.judge_results(HAND_MADE, J.OfflineJudge())
    assert [r["offline_score"] for r in out][2] == 1.0
    assert out[0]["offline_score"] > 6 > out[1]["offline_score"]
    assert all(set(r) == set(h) | {"offline_score"} for r, h in zip(out, HAND_MADE))
    assert "offline_score" not in HAND_MADE[0]  # input left alone
    assert summary["n"] == 3 and summary["n_failed"] == 1 and summary["judge"] == "offline"
    s = summary["subsets"]
    assert (s["SSVTP"]["n"], s["HCT"]["n"], s["overall"]["n"]) == (1, 2, 3)
    assert (s["SSVTP"]["n_failed"], s["HCT"]["n_failed"]) == (0, 1)
    assert s["HCT"]["mean"] == pytest.approx((out[1]["offline_score"] + 1.0) / 2)
    assert s["HCT"]["gpt4_mean"] == 2.0 and s["HCT"]["n_gpt4"] == 1  # "garbled" does not parse
    assert s["overall"]["gpt4_mean"] == 5.0


@pytest.mark.parametrize("records, fragment", [
    ({"label": "x"}, "JSON list"),
    ([], "empty"),
    (["hard"], "not an object"),
    ([{"generated response": "hard"}], "'label'"),
    ([{"label": "hard"}], "'generated response'"),
    ([{"label": "", "generated response": "hard"}], "label"),
    ([{"label": "hard", "generated response": 3}], "string or null"),
])
def test_check_records_rejects(records, fragment):
    with pytest.raises(DataError, match=fragment):
        J.check_records(records)


# --------------------------------------------------------------------------- CLI


def test_cli_round_trip_on_a_new_file(tmp_path, capsys):
    src, out = tmp_path / "in.json", tmp_path / "sub" / "scored.json"
    src.write_text(json.dumps(HAND_MADE))
    assert main(["judge", str(src), "--out", str(out)]) == 0
    scored = json.loads(out.read_text())
    assert [r["label"] for r in scored] == [r["label"] for r in HAND_MADE]
    assert scored[2]["offline_score"] == 1.0 and all(1 <= r["offline_score"] <= 10 for r in scored)
    text = capsys.readouterr().out
    assert "1 failed" in text and "SSVTP" in text and "HCT" in text and "overall" in text
    assert sorted(p.name for p in out.parent.iterdir()) == ["scored.json"]  # no temp left
    assert main(["judge", str(src), "--out", str(out), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["results"]["subsets"]["HCT"]["n_failed"] == 1


@needs_data
def test_cli_round_trip_on_tvl_results(tmp_path, capsys):
    src = J.judge_data_dir() / "tvl_llama_vits.json"
    out = tmp_path / "scored.json"
    assert main(["judge", str(src), "--out", str(out)]) == 0
    scored = json.loads(out.read_text())
    assert len(scored) == 402 and all("offline_score" in r for r in scored)
    text = capsys.readouterr().out
    assert "402 responses, 0 failed" in text
    overall = next(x for x in text.splitlines() if x.startswith("overall")).split()
    assert abs(float(overall[3]) - float(overall[-1])) < 0.5  # offline vs GPT-4 mean
    assert overall[4].startswith("[")  # its 95 % bootstrap CI


@needs_data
def test_cli_validate(capsys):
    assert main(["judge", "--validate"]) == 0
    text = capsys.readouterr().out
    assert "Spearman rho with GPT-4" in text and "ranking offline" in text


@pytest.mark.parametrize("content, fragment", [
    ("{not json", "not valid JSON"),
    ('{"label": "hard", "generated response": "hard"}', "JSON list"),
    ('[{"label": "hard"}]', "generated response"),
    ('[{"generated response": "hard"}]', "label"),
    (None, "does not exist"),
])
def test_cli_bad_input_writes_nothing(tmp_path, capsys, content, fragment):
    src, out = tmp_path / "in.json", tmp_path / "out" / "scored.json"
    if content is not None:
        src.write_text(content)
    assert main(["judge", str(src), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and fragment in err
    assert not out.parent.exists()
    # an existing output is left untouched
    out.parent.mkdir()
    out.write_text("keep")
    assert main(["judge", str(src), "--out", str(out)]) == 2
    assert out.read_text() == "keep" and sorted(p.name for p in out.parent.iterdir()) == ["scored.json"]


@pytest.mark.parametrize("argv", [["judge"], ["judge", "{tmp}/in.json"],
                                  ["judge", "--out", "{tmp}/o.json"],
                                  ["judge", "{tmp}/in.json", "--out", "{tmp}/o.json",
                                   "--judge", "llm", "--endpoint", "not a url"],
                                  ["judge", "--explain"], ["judge", "--compare"],
                                  ["judge", "{tmp}/in.json", "{tmp}/in.json", "--out",
                                   "{tmp}/o.json"],
                                  ["judge", "{tmp}/in.json", "--compare"],  # no endpoint
                                  ["judge", "{tmp}/in.json", "--compare", "--out", "{tmp}/o.json",
                                   "--endpoint", "http://127.0.0.1:9/v1"]])
def test_cli_usage_errors(tmp_path, capsys, monkeypatch, argv):
    monkeypatch.delenv("RATOUCH_JUDGE_ENDPOINT", raising=False)
    (tmp_path / "in.json").write_text(json.dumps(HAND_MADE))
    assert main([a.format(tmp=tmp_path) for a in argv]) == 2
    assert "error" in capsys.readouterr().err
    assert not (tmp_path / "o.json").exists()


# --------------------------------------------------------------------------- LLM judge


@pytest.fixture
def fake_llm(monkeypatch):
    monkeypatch.delenv(KEY_ENV, raising=False)
    with serve_fake_llm(monkeypatch, "8\nThe answer matches most of the correct adjectives.") as state:
        yield state


def _judge(state: FakeLLM, **kw) -> J.LLMJudge:
    cfg = {"endpoint": state.endpoint, "model": "judge-model", "api_key_env": KEY_ENV,
           "timeout_s": 5.0, "max_attempts": 2, **kw}
    return J.LLMJudge(J.LLMJudgeConfig(**cfg))


def test_llm_judge_prompt_key_and_score(fake_llm, monkeypatch):
    monkeypatch.setenv(KEY_ENV, "sk-judge-123")
    j = _judge(fake_llm)
    assert j.score("smooth, glossy, patterned", "hard, smooth, flat, splotchy.") == 8.0
    (seen,) = fake_llm.requests
    assert seen["path"] == "/v1/chat/completions"
    assert seen["headers"]["Authorization"] == "Bearer sk-judge-123"
    body = seen["body"]
    assert body["model"] == "judge-model" and body["temperature"] == 0.0
    assert [m["role"] for m in body["messages"]] == ["system", "user"]
    prompt = body["messages"][1]["content"]
    assert prompt == J.build_judge_prompt("smooth, glossy, patterned", "hard, smooth, flat, splotchy.")
    assert "smooth, glossy, patterned" in prompt and "hard, smooth, flat, splotchy." in prompt
    assert J.TVL_QUESTION in prompt and "1 to 10" in prompt
    assert j.stats() == {"n_requests": 1, "n_errors": 0, "n_unparseable": 0, "n_fallbacks": 0}


def test_llm_judge_without_key_sends_no_authorization(fake_llm):
    fake_llm.reply = "7.5\nok"
    assert _judge(fake_llm).score("hard", "hard") == 7.5
    assert "Authorization" not in fake_llm.requests[0]["headers"]


def test_llm_judge_server_error_falls_back(fake_llm, monkeypatch, caplog):
    monkeypatch.setenv(KEY_ENV, "sk-secret-xyz")
    fake_llm.mode = "http500"
    j = _judge(fake_llm, max_attempts=3)
    with caplog.at_level("DEBUG"):
        got = j.score("soft, plush", "soft, cushioned")
    assert got == J.OfflineJudge().score("soft, plush", "soft, cushioned")
    assert len(fake_llm.requests) == 3
    assert j.stats() == {"n_requests": 3, "n_errors": 3, "n_unparseable": 0, "n_fallbacks": 1}
    assert "sk-secret-xyz" not in caplog.text


def test_llm_judge_unparseable_reply_falls_back(fake_llm):
    fake_llm.reply = "The assistant did well, I would say about 8."
    j = _judge(fake_llm)
    assert j.score("hard", "hard, rigid") == J.OfflineJudge().score("hard", "hard, rigid")
    assert j.stats() == {"n_requests": 2, "n_errors": 0, "n_unparseable": 2, "n_fallbacks": 1}


def test_llm_judge_timeout_falls_back(fake_llm):
    fake_llm.mode = "sleep"
    j = _judge(fake_llm, timeout_s=0.2, max_attempts=2)
    assert j.score("hard", "soft") == J.OfflineJudge().score("hard", "soft")
    # both attempts timed out (a client that waited would have got the server's late answer)
    assert j.n_errors == 2 and j.n_fallbacks == 1


def test_llm_judge_results_and_cli(fake_llm, tmp_path, capsys, monkeypatch):
    j = _judge(fake_llm)
    out, summary = J.judge_results(HAND_MADE, j)
    assert [r["llm_score"] for r in out] == [8.0, 8.0, 1.0]
    assert len(fake_llm.requests) == 2  # the failed generation is not sent
    assert summary["score_key"] == "llm_score" and summary["n_failed"] == 1
    assert summary["n_fallbacks"] == 0
    src, dst = tmp_path / "in.json", tmp_path / "scored.json"
    src.write_text(json.dumps(HAND_MADE))
    monkeypatch.setenv("RATOUCH_JUDGE_ENDPOINT", fake_llm.endpoint)
    assert main(["judge", str(src), "--out", str(dst), "--judge", "llm"]) == 0
    assert [r["llm_score"] for r in json.loads(dst.read_text())] == [8.0, 8.0, 1.0]
    assert "fallbacks to the offline judge 0" in capsys.readouterr().out


@pytest.mark.parametrize("kw, fragment", [
    ({"endpoint": "ftp://x/v1"}, "endpoint"), ({"endpoint": ""}, "endpoint"),
    ({"max_attempts": 0}, "max_attempts"), ({"timeout_s": 0}, "timeout_s"),
    ({"temperature": 3}, "temperature"), ({"model": ""}, "model"),
])
def test_llm_judge_config_rejects(kw, fragment):
    with pytest.raises(ConfigError, match=fragment):
        J.LLMJudgeConfig(**{"endpoint": "http://127.0.0.1:9/v1", **kw})


def test_cli_explain_shows_each_word_and_its_weight(tmp_path, capsys):
    src = tmp_path / "in.json"
    src.write_text(json.dumps(HAND_MADE))
    assert main(["judge", str(src), "--explain"]) == 0
    text = capsys.readouterr().out
    assert "[0] score" in text and "label: soft, plush, fabric" in text
    assert "matched" in text and "weight" in text and "~ plush" in text
    assert "clash" in text  # "rough, matte, soft" against "hard, smooth, glossy"
    assert "failed answer, scored 1" in text
    assert not list(tmp_path.glob("*.json"))[1:]  # nothing written
    assert main(["judge", str(src), "--explain", "--json"]) == 0
    (explained,) = json.loads(capsys.readouterr().out)["explain"].values()
    words = {t["word"]: t for t in explained[1]["words"]}
    assert words["soft"]["status"] == "clash" and 0 < words["soft"]["weight"] <= 1
    assert explained[0]["score"] == pytest.approx(J.OfflineJudge().score_many(
        [(r["label"], r["generated response"]) for r in HAND_MADE])[0])


def test_cli_compare_with_a_local_llm_judge(tmp_path, capsys, monkeypatch):
    """`judge --compare`: the offline judge's agreement with a (fake) LLM judge on own files."""
    monkeypatch.delenv(KEY_ENV, raising=False)
    labels = ["soft, plush, fabric", "hard, smooth, glossy", "rough, coarse, uneven",
              "soft, woven, fibrous", "hard, metallic, cold"] * 4
    good = ["soft, plush", "hard, smooth, rigid", "rough, coarse", "woven, soft", "hard, metallic"]
    bad = ["hard, rigid", "rough, matte", "smooth, glossy", "hard, metallic", "soft, plush"]
    files = []
    for name, answers in (("good", good * 4), ("mixed", (good[:2] + bad[2:]) * 4),
                          ("bad", bad * 4)):
        path = tmp_path / f"{name}.json"
        path.write_text(json.dumps([{"label": lab, "generated response": a}
                                    for lab, a in zip(labels, answers)]))
        files.append(str(path))
    with serve_fake_llm(monkeypatch, "") as state:
        state.mode = "grade"
        argv = ["judge", *files, "--compare", "--endpoint", state.endpoint,
                "--api-key-env", KEY_ENV]
        assert main(argv + ["--json"]) == 0
        r = json.loads(capsys.readouterr().out)["compare"]
        assert main(argv) == 0
        text = capsys.readouterr().out
    assert list(r["files"]) == files and r["llm"]["n_fallbacks"] == 0
    assert r["llm"]["n_requests"] == 60
    f = r["files"]
    assert f[files[0]]["llm_mean"] > f[files[1]]["llm_mean"] > f[files[2]]["llm_mean"]
    assert f[files[0]]["offline_mean"] > f[files[1]]["offline_mean"] > f[files[2]]["offline_mean"]
    assert r["pooled_spearman"] > 0.7
    for s in f.values():
        assert s["mean_diff"] == pytest.approx(s["offline_mean"] - s["llm_mean"])
    assert "pooled Spearman rho" in text and "good.json" in text


def test_cli_ttest_prints_ci_f1_and_length(tmp_path, capsys):
    out = {}
    for name, answers in (("a", ["soft", "hard", None]), ("b", ["soft, plush", "hard, smooth",
                                                                "bumpy"])):
        recs = [{**r, "generated response": a} for r, a in zip(HAND_MADE, answers)]
        src, dst = tmp_path / f"{name}.json", tmp_path / f"{name}_scored.json"
        src.write_text(json.dumps(recs))
        assert main(["judge", str(src), "--out", str(dst)]) == 0
        out[name] = str(dst)
    capsys.readouterr()
    assert main(["eval", "ttest", out["a"], out["b"]]) == 0
    text = capsys.readouterr().out
    overall = next(x for x in text.splitlines() if x.strip().startswith("overall") and "A " in x)
    assert overall.count("[") == 2 and "F1" in overall and "adj" in overall
    assert main(["eval", "ttest", out["a"], out["b"], "--json"]) == 0
    r = json.loads(capsys.readouterr().out)["subsets"]["overall"]
    assert r["stats_a"]["mean_length"] == pytest.approx(2 / 3, abs=1e-4)
    assert r["stats_b"]["ci_low"] <= r["mean_b"] <= r["stats_b"]["ci_high"]
