"""The paper's experiments: variant training from stage 1, the disk cache, the reports."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from conftest import HAVE_ASSETS
from ratouch.errors import ConfigError
from ratouch.eval.experiments import (
    BASELINE,
    RA_TOUCH,
    ExperimentConfig,
    Lab,
    Variant,
    make_integrator,
    results_markdown,
    run_experiments,
)
from ratouch.search.index import exact_topk


def test_exact_topk_matches_a_full_sort():
    rng = np.random.default_rng(0)
    q, keys = rng.normal(size=(7, 16)), rng.normal(size=(50, 16))
    ids = exact_topk(q, keys, 5, max_bytes=3 * 4 * len(keys))  # 3 queries per chunk
    full = np.argsort(-(q @ keys.T), axis=1)[:, :5]
    assert (ids == full).all()
    assert exact_topk(q, keys[:3], 5).shape == (7, 3)  # K larger than the corpus


@pytest.mark.parametrize("integration", ["image", "text", "both", "sum"])
def test_integrators_start_at_zero_and_have_the_right_width(integration):
    m = make_integrator(replace(RA_TOUCH, integration=integration), 24, 16)
    T, R = torch.randn(3, 24), torch.randn(3, 5, 24)
    assert torch.equal(m(T, R, R), torch.zeros(3, 16))  # p' = p at step 0


def test_unknown_integration_and_bad_config_are_refused():
    with pytest.raises(ConfigError):
        make_integrator(replace(RA_TOUCH, integration="neither"), 24, 16)
    with pytest.raises(ConfigError):
        ExperimentConfig(steps=0)
    with pytest.raises(ConfigError):
        run_experiments(["table9"], ExperimentConfig(), "unused")


@pytest.fixture(scope="module")
def lab(pipeline, world):
    """A lab over the small shipped-encoder corpus, with 48 training pairs and 21 test pairs."""
    from ratouch.world.splits import encode_test_split

    lab = Lab(ExperimentConfig(steps=2, batch=8, workers=1, ks=(1, 3), corpus_sizes=(100, 600)))
    lab.__dict__["pipeline"] = pipeline
    samples = [world.sample("train", i) for i in range(48)]
    enc = pipeline.encoders
    lab.__dict__["train"] = {
        "V": enc.encode_image([s.crop for s in samples]),
        "T": enc.encode_tactile([s.tactile for s in samples]),
        "labels": [s.caption for s in samples], "materials": [s.material for s in samples]}
    lab.__dict__["test"] = encode_test_split(enc, indices=range(0, 402, 20))
    return lab


def test_subset_ids_are_stratified_and_nested(lab):
    a, b = lab.subset_ids(100), lab.subset_ids(300)
    assert len(a) == 100 and len(b) == 300 and set(a) <= set(b)
    classes = {lab.pipeline.corpus.entry(int(i)).class_name for i in a}
    assert len(classes) >= 90  # 100 entries spread over the classes, not one class's first 100
    assert len(lab.subset_ids(0)) == len(lab.pipeline.corpus)


def test_neighbours_follow_the_variant(lab):
    V, T = lab.test.V[:4], lab.test.T[:4]
    ids, rv, rl = lab.neighbours(replace(RA_TOUCH, k=3, corpus_size=100), V, T)
    assert ids.shape == (4, 3) and set(ids.ravel()) <= set(lab.subset_ids(100))
    assert rv.shape == rl.shape == (4, 3, lab.pipeline.encoders.dim)
    _, _, rl_names = lab.neighbours(replace(RA_TOUCH, caption="class_name", k=3), V, T)
    assert not np.allclose(rl, rl_names)


def test_an_experiment_trains_judges_caches_and_reports(lab, tmp_path, monkeypatch):
    reports = run_experiments(["table2"], lab.cfg, tmp_path, lab, png=False)
    rep = reports[0]
    assert rep.markdown.count("\n|") >= 4  # header rule + baseline + two variants
    assert "baseline (no retrieval)" in rep.markdown and "p=" in rep.markdown
    for ext in ("md", "html", "json", "data.json"):
        assert (tmp_path / "figures" / f"table2.{ext}").is_file()
    res = lab.evaluate([BASELINE, RA_TOUCH])
    for r in res.values():
        assert len(r["scores"]) == len(lab.test.labels)
        assert all(1.0 <= s <= 10.0 for s in r["scores"])
        assert set(r["means"]) == {"SSVTP", "HCT", "overall"}
    # a fresh lab finds every variant in the disk cache and trains nothing
    fresh = Lab(lab.cfg)
    fresh.__dict__.update({k: lab.__dict__[k] for k in ("pipeline", "train", "test")})
    monkeypatch.setattr(Lab, "_train_many", lambda *a: pytest.fail("retrained a cached variant"))
    assert fresh.evaluate([BASELINE, RA_TOUCH])[RA_TOUCH]["scores"] == res[RA_TOUCH]["scores"]
    md = results_markdown(reports, lab.cfg, 12.0)
    assert "commit" in md and "Table 2" in md and "figures/table2.png" in md
    assert "* commit `abc1234`," in results_markdown(reports, lab.cfg, 12.0, commit="abc1234")


def test_the_report_names_the_commit_the_run_began_on(monkeypatch, tmp_path):
    """`ratouch eval all` writes its figures into the tracked docs/ as it goes: the commit is
    read before the run, not after (which would read the run's own output as "+changes")."""
    import argparse

    from ratouch.cli import experiments as cli

    answers = iter(["1234abc", "1234abc+changes"])
    monkeypatch.setattr(cli, "git_commit", lambda: next(answers))
    monkeypatch.setattr(cli, "Lab", lambda cfg: argparse.Namespace(counts=None))
    monkeypatch.setattr(cli, "run_experiments", lambda names, cfg, out, lab: [])
    args = argparse.Namespace(encoder="default-s", steps=1, seed=0, workers=1,
                              eval_cmd="all", out=str(tmp_path))
    assert cli.run(args) == 0
    assert "* commit `1234abc`," in (tmp_path / "results.md").read_text()


def test_the_speed_chart_on_the_page_says_when_it_was_measured_not_when_checked_out(
        monkeypatch, tmp_path):
    """The results page quotes `ratouch bench tradeoff`'s figures. It used to stamp them with
    the file's modification time, which in a fresh clone is the checkout's: a chart measured
    days before read as made that minute. The stamp now comes from what the bench recorded,
    else from the last commit that changed the file, else it says it is not recorded."""
    import argparse
    import json
    import os

    from ratouch.cli import bench as cli
    from ratouch.eval import report
    from ratouch.eval.experiments import results

    figs = tmp_path / "figures"
    figs.mkdir()
    (figs / "tradeoff.md").write_text("## Speed against accuracy\n\n```\nrows\n```\n")
    (figs / "tradeoff.data.json").write_text('{"points": []}')  # from before it was recorded
    os.utime(figs / "tradeoff.md")  # "checked out" now
    monkeypatch.setattr(report, "last_commit", lambda *paths: None)
    assert "Made by `ratouch bench tradeoff` (date not recorded)." in \
        results.companion_sections(tmp_path)
    monkeypatch.setattr(report, "last_commit", lambda *paths: ("2026-11-29", "85f3b2e"))
    assert "(committed 2026-11-29 in `85f3b2e`)." in results.companion_sections(tmp_path)

    # the bench records the commit it measured (read before it writes into the tree) and when
    monkeypatch.setattr(cli, "git_commit", lambda: "1234abc")
    monkeypatch.setattr(cli, "bench_tradeoff", lambda **kw: {"points": [], "settings": {}})
    monkeypatch.setattr(cli, "format_tradeoff", lambda r: "rows")
    monkeypatch.setattr(cli, "tradeoff_figure", lambda r: None)
    args = argparse.Namespace(indexes="flat", sizes="1000", ks="5", encoders="", n=1,
                              json=False, out=str(tmp_path))
    assert cli._bench_tradeoff(args) == 0
    made = json.loads((figs / "tradeoff.data.json").read_text())["made"]
    assert made["commit"] == "1234abc" and made["utc"].endswith(" UTC")
    page = results.companion_sections(tmp_path)
    assert f"Made by `ratouch bench tradeoff` ({made['utc']}, commit `1234abc`)." in page
    assert "committed 2026-11-29" not in page


def test_variant_labels_are_distinct():
    vs = [BASELINE, RA_TOUCH, replace(RA_TOUCH, k=7), replace(RA_TOUCH, mode="image"),
          replace(RA_TOUCH, corpus_size=100), Variant(integration="sum")]
    assert len({v.label() for v in vs}) == len(vs)


def test_withheld_materials_table(lab, tmp_path):
    cfg = replace(lab.cfg, stage1_steps=2, withheld=3)
    small = Lab(cfg)
    small.__dict__.update({k: lab.__dict__[k] for k in ("pipeline", "train", "test")})
    held = small.withheld_materials(3)
    assert len(held) == 3 and held == small.withheld_materials(3)
    assert not set(held) & set(small.train_for(3)["materials"])
    rep = run_experiments(["table6"], cfg, tmp_path, small, png=False)[0]
    assert "withheld materials" in rep.markdown and ", ".join(held) in rep.markdown
    with pytest.raises(ConfigError):
        small.withheld_materials(10_000)


def test_score_charts_show_paired_differences_with_cis():
    """7.94 vs 7.98 must be visible: the chart plots differences from the baseline with their
    paired 95 % CIs, not bars from zero."""
    from ratouch.eval.experiments import _diff_chart, paired_difference

    rng = np.random.default_rng(0)
    base = rng.uniform(7, 9, 200)
    better = base + 0.04 + rng.normal(0, 0.05, 200)
    mean, lo, hi = paired_difference(base, better)
    assert lo < 0.04 < hi and lo > 0 and mean == pytest.approx(0.04, abs=0.01)
    subsets = ["structured"] * 20 + ["wild"] * 180
    fig = _diff_chart("t", ["RA-Touch"], [{"scores": better}], {"scores": base}, subsets)
    assert [t.type for t in fig.data] == ["scatter"] * 3
    overall = fig.data[2]
    assert overall.y[0] == pytest.approx(mean) and overall.error_y.array[0] == pytest.approx(
        hi - mean)


def test_source_sha256_follows_the_source_of_modules_and_packages(tmp_path, monkeypatch):
    import sys

    from ratouch.eval.experiments import source_sha256

    pkg = tmp_path / "fakepkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "loop.py").write_text("STEPS = 1\n")
    (tmp_path / "fakemod.py").write_text("LR = 0.1\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    for name in ("fakepkg", "fakemod"):
        monkeypatch.delitem(sys.modules, name, raising=False)
    before = source_sha256(("fakepkg", "fakemod"))
    assert source_sha256(("fakepkg", "fakemod")) == before
    (pkg / "loop.py").write_text("STEPS = 2\n")  # a module of the package, never imported
    after_pkg = source_sha256(("fakepkg", "fakemod"))
    (tmp_path / "fakemod.py").write_text("LR = 0.2\n")
    assert len({before, after_pkg, source_sha256(("fakepkg", "fakemod"))}) == 3
    assert len(source_sha256()) == 64  # the real training code is found


@pytest.mark.skipif(not HAVE_ASSETS, reason="the shipped generator/retriever are not in assets/")
def test_a_change_to_the_training_code_retrains_instead_of_reusing(tmp_path, monkeypatch):
    """Results cached before the code that trains a variant changed are not reused."""
    from types import SimpleNamespace

    from ratouch.eval.experiments import lab as experiments  # Lab reads source_sha256 there

    monkeypatch.setenv("RATOUCH_CACHE", str(tmp_path))
    stub = SimpleNamespace(corpus=SimpleNamespace(manifest={"metadata_sha256": "c"}),
                           encoders=SimpleNamespace(weights_fingerprint="w"))

    def lab_with_code(code: str) -> Lab:
        monkeypatch.setattr(experiments, "source_sha256", lambda: code)
        lab = Lab(ExperimentConfig())
        lab.__dict__["pipeline"] = stub
        assert lab.code_sha256 == code  # read once per lab
        return lab

    old = lab_with_code("code before")
    old._save(RA_TOUCH, {"responses": ["soft"], "train_seconds": 1.0})
    assert lab_with_code("code before")._load(RA_TOUCH)["responses"] == ["soft"]
    new = lab_with_code("code after")
    assert new._key(RA_TOUCH) != old._key(RA_TOUCH)
    assert new._load(RA_TOUCH) is None  # evaluate() trains it again


def test_a_report_write_killed_at_any_step_leaves_each_file_old_or_new(tmp_path, monkeypatch):
    """`ratouch eval NAME --out R` rewrites R's files: a run that dies between any two of its
    renames leaves every file whole (the previous report's or the new one's), never empty."""
    import os

    import plotly.graph_objects as go

    from ratouch.eval.experiments import Report, write_report

    def report(v: str) -> Report:
        return Report("table4", f"Table 4 ({v})", f"| run | {v} |", go.Figure(go.Bar(y=[len(v)])),
                      {"v": v})

    def contents() -> dict[str, bytes]:
        return {p.name: p.read_bytes() for p in out.iterdir() if not p.name.startswith(".")}

    out = tmp_path / "new"
    write_report(report("new"), out, png=False)
    new = contents()
    out = tmp_path / "R"
    write_report(report("old"), out, png=False)
    old = contents()
    real, moves = os.replace, []

    class Killed(BaseException):
        pass

    def dying(src, dst):
        moves.append(dst)
        if len(moves) == step:
            raise Killed
        return real(src, dst)

    for step in range(1, 5):
        write_report(report("old"), out, png=False)
        moves.clear()
        with monkeypatch.context() as m, pytest.raises(Killed):
            m.setattr(os, "replace", dying)
            write_report(report("new"), out, png=False)
        seen = contents()
        for name, data in seen.items():
            if name.endswith(".html"):  # plotly gives each page a new div id: whole is enough
                assert data.rstrip().endswith(b"</html>"), (step, name)
            elif name in old:
                assert data in (old[name], new[name]), (step, name)
        assert seen["table4.md"] == (new if step > 1 else old)["table4.md"]


def test_seeded_build_draws_the_same_module_whatever_the_callers_stream():
    from ratouch.seeds import seeded_build

    def build():
        return make_integrator(RA_TOUCH, 24, 16)

    made = []
    for caller_seed in (1, 2):
        torch.manual_seed(caller_seed)
        before = torch.get_rng_state()
        made.append(seeded_build(0, build).state_dict())
        assert torch.equal(torch.get_rng_state(), before)  # the caller's stream did not move
    assert all(torch.equal(made[0][k], made[1][k]) for k in made[0])
    other = seeded_build(1, build).state_dict()
    assert not all(torch.equal(made[0][k], other[k]) for k in made[0])


def test_a_variant_starts_from_the_same_integrator_in_every_process(lab, monkeypatch):
    """torch seeds its generator afresh in each process: a variant's integrator must not be
    drawn from it (docs/premise.md, "Why a variant's training was not repeatable")."""
    from ratouch.eval.experiments import lab as lab_module

    real, starts = lab_module.train_stage2, []

    def spy(stage1, integrator, *args, **kwargs):
        starts.append({k: t.clone() for k, t in integrator.state_dict().items()})
        return real(stage1, integrator, *args, **kwargs)

    monkeypatch.setattr(lab_module, "train_stage2", spy)
    v = replace(RA_TOUCH, k=3)
    answers = []
    for process_seed in (11, 12):  # stands for two processes' different initial seeds
        torch.manual_seed(process_seed)
        job = (lab.stage1, lab.train, lab.test, lab.cfg, v, lab._inputs(v))
        answers.append(lab_module._run_variant(job)[1])
    assert all(torch.equal(starts[0][k], starts[1][k]) for k in starts[0])
    assert answers[0] == answers[1]
