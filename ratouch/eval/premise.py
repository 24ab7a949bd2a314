"""The paper's premise on the world: does retrieval help where paired touch data is scarce?

`run_premise` renders two held-out groups (materials that are scarce in the paired training
split, and materials that are seen often; `ratouch.world.scarcity`), and for each of several
runs (a training seed and a draw of the scarce materials' few pairs) compares the baseline with
RA-Touch under every control of `ratouch.eval.controls`. Run 0 is the shipped generators; the
others retrain stages 1 and 2 of both systems into the cache on first use (about 8 minutes
each on 2 cores), from the shared language prior, encoders and retriever.

The verdict applies the criteria pre-registered in docs/premise.md.
"""

from __future__ import annotations

import copy
import dataclasses
import logging
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import torch
from scipy import stats

from ratouch.errors import ConfigError
from ratouch.eval.answer import BASELINE, RA_TOUCH, answer_split, judge_answers, retrieve
from ratouch.eval.catalog import ARM_NAMES
from ratouch.eval.controls import derangement, run_controls, vote
from ratouch.eval.experiments import source_sha256
from ratouch.eval.judge import OfflineJudge
from ratouch.model.generator import load_generator
from ratouch.model.integrator import IntegratorConfig, TextureAwareIntegrator
from ratouch.paths import cache_dir, generator_weights
from ratouch.search.modes import QUERY_MODES
from ratouch.search.retrieval import mode_query
from ratouch.seeds import seeded_build
from ratouch.serve.pipeline import RATouchPipeline, integrator_factory, load_for_serving
from ratouch.timing import Progress, bars, say_to
from ratouch.train.recipes import (
    generator_recipe,
    reader_recipe,
    text_arm_recipe,
    token_arm_recipe,
    training_pairs,
)
from ratouch.vocabulary import adjective_f1, parse_adjectives
from ratouch.world.config import WorldConfig
from ratouch.world.sampler import TEST_SIZE
from ratouch.world.scarcity import ScarceRegime, premise_indices
from ratouch.world.splits import TestSplit, encode_test_split

log = logging.getLogger(__name__)

GROUPS = ("seen", "scarce")
PAPER_EFFECT = 0.3  # the paper's gains on TVL: +0.24 .. +0.37 (Table 1)
COPY_MARGIN = 0.5   # the corpus "knows what the baseline lacks" above baseline + this
MIN_GAIN = 0.1      # a gain below this is no gain


def group_split(encoders, group: str, n: int, regime: ScarceRegime) -> TestSplit:
    """`n` held-out renders of a material group, encoded."""
    return encode_test_split(encoders, WorldConfig(seed=regime.seed),
                             premise_indices(group, n, regime), split="probe")


def run_folder(encoder: str, run: int, lm: str | None = None) -> Path:
    """Where run `run`'s generators (on the pretrained language model `lm` when given) are
    trained (keyed by the code that trains them)."""
    name = encoder + (f"+{lm}" if lm else "")
    return cache_dir() / f"premise-{name}-run{run}-{source_sha256()[:12]}"


def run_generators(encoder: str, run: int, progress: bool = False, lm: str | None = None):
    """(RA-Touch, baseline) of a run, LoRA merged; run 0 is the shipped pair (on `lm`'s
    generators when given: only run 0 exists there, `check_lm_runs`)."""
    if run == 0:
        folders = {k: generator_weights(encoder, k, lm) for k in ("ra", "baseline")}
    else:
        check_lm_runs(lm, run + 1)
        root = run_folder(encoder, run)
        if not (root / "ra" / "manifest.json").is_file():
            log.info("premise run %d: training both generators into %s", run, root)
            generator_recipe(encoder, seed=run, draw=run, world_seed=0, out=root,
                             progress=progress)
        folders = {k: root / k for k in ("ra", "baseline")}
    return load_for_serving(folders["ra"]), load_for_serving(folders["baseline"], integrator=False)


def check_lm_runs(lm: str | None, runs: int) -> None:
    """Premise runs on a pretrained language model's generators: only run 0 (the shipped
    pair, trained on draw 0 by `ratouch train generator --lm`) exists; more runs would each
    retrain that model on another draw (about 20 min on 2 CPU cores), which is not built."""
    if lm is not None and runs != 1:
        raise ConfigError(f"runs={runs}: on the generators of --lm {lm} only run 0 (the "
                          "shipped pair) exists; use --runs 1")


def _run_arm(encoder: str, run: int, name: str, recipe, progress: bool,
             lm: str | None = None):
    """A second-stage arm of a run (folder `name` of the run's cache folder), trained there on
    first use by `recipe` from the run's stage-1 model with RA-Touch's stage-2 budget (on the
    generators of `lm` when given); LoRA merged."""
    root = run_folder(encoder, run, lm)
    ra = generator_weights(encoder, "ra", lm) if run == 0 else root / "ra"
    if not (root / name / "manifest.json").is_file():
        log.info("premise run %d: training the %s arm into %s", run, name, root)
        recipe(encoder, ra, seed=run, draw=run, world_seed=0, out=root / name,
               progress=progress)
    return load_for_serving(root / name)


def token_arm(encoder: str, run: int, progress: bool = False, lm: str | None = None):
    """The run's neighbour-token arm (second arm; `token_arm_recipe`)."""
    return _run_arm(encoder, run, "tokens", token_arm_recipe, progress, lm)


def text_arm(encoder: str, run: int, progress: bool = False, lm: str | None = None):
    """The run's text arm: the neighbours' captions written into the prompt
    (`text_arm_recipe`)."""
    return _run_arm(encoder, run, "text", text_arm_recipe, progress, lm)


#: The second-stage arms `run_premise` can judge beside RA-Touch (`catalog.ARM_NAMES`): name
#: -> the function giving a run's trained arm.
ARMS = {"tokens": token_arm, "text": text_arm}
if tuple(ARMS) != ARM_NAMES:
    raise ConfigError(f"premise.ARMS {tuple(ARMS)} must implement catalog.ARM_NAMES {ARM_NAMES}")


def reader(encoder: str, run: int, progress: bool = False):
    """The run's reader, the `gated` system's generator (`reader_recipe`): run 0's is the
    shipped one where it exists, else it is trained into the run's cache folder."""
    shipped = generator_weights(encoder, "reader")
    if run == 0 and (shipped / "manifest.json").is_file():
        return load_for_serving(shipped)
    return _run_arm(encoder, run, "reader", reader_recipe, progress)


def _own_and_shuffled(p: RATouchPipeline, split: TestSplit, ids: np.ndarray, name: str,
                      judge, seed: int, generator=None) -> dict[str, np.ndarray]:
    """Judge scores of a RA-Touch arm reading `ids` ({name}) and another query's ({name}
    _shuffled: a derangement)."""
    return {n: answer_split(p, split, RA_TOUCH, ids=nb, generator=generator, name=n,
                            judge=judge).scores
            for n, nb in ((name, ids), (f"{name}_shuffled", ids[derangement(len(ids), seed)]))}


def _arm_scores(p: RATouchPipeline, arms: dict, split: TestSplit, k: int, judge, seed: int
                ) -> dict[str, np.ndarray]:
    """Judge scores of each arm ({name: generator}) with its own and with shuffled
    neighbours of the joint query (the neighbours the paper's RA-Touch reads)."""
    ids = p.joint_neighbours(split.V, split.T, k)
    out: dict[str, np.ndarray] = {}
    for name, gen in arms.items():
        out.update(_own_and_shuffled(p, split, ids, name, judge, seed, generator=gen))
    return out


def arms_on_test(p: RATouchPipeline, arms: dict, split: TestSplit, k: int, judge
                 ) -> dict[str, np.ndarray]:
    """Judge scores on the world test split of the baseline, the `paper` system and each arm
    on the paper's neighbours (the joint query's top k)."""
    ids = p.joint_neighbours(split.V, split.T, k)
    return {"baseline": answer_split(p, split, BASELINE, judge=judge).scores,
            "paper": answer_split(p, split, RA_TOUCH, ids=ids, judge=judge,
                                  name="paper").scores,
            **{name: answer_split(p, split, RA_TOUCH, ids=ids, generator=gen, name=name,
                                  judge=judge).scores for name, gen in arms.items()}}


def summarise_test(results: list[dict[str, np.ndarray]], seed: int = 0) -> dict:
    """The arms on the world test split over runs: each system's mean score, and each arm's
    difference to the baseline and to `paper`, with pooled CIs and p."""
    out: dict = {"n": len(results[0]["baseline"]),
                 "score": {name: round(float(np.mean([r[name].mean() for r in results])), 4)
                           for name in results[0]}}
    for name in results[0]:
        if name in ("baseline", "paper"):
            continue
        for ref in ("baseline", "paper"):
            diffs = [r[name] - r[ref] for r in results]
            out[f"{name}_vs_{ref}"] = {
                "diff": round(float(np.mean([d.mean() for d in diffs])), 4),
                "ci95": [round(x, 4) for x in pooled_ci(diffs, seed)], "p": _p_value(diffs)}
    return out


def _gated_scores(p: RATouchPipeline, split: TestSplit, k: int, judge, seed: int
                  ) -> dict[str, np.ndarray]:
    """Judge scores of the `gated` system (its answer as the pipeline routes it,
    `system_generator`, reading the trust-gated query's neighbours) and of the reader alone
    on them ("reader"), each with its own and with shuffled neighbours."""
    ids = retrieve(p, split.V, split.T, k, "gated")
    out = _own_and_shuffled(p, split, ids, "gated", judge, seed,
                            generator=p.system_generator("gated"))
    if p.generator_reader is not None:
        out.update(_own_and_shuffled(p, split, ids, "reader", judge, seed,
                                     generator=p.generator_reader))
    return out


def touch_withheld_scores(p: RATouchPipeline, split: TestSplit, k: int, judge, seed: int
                          ) -> dict[str, np.ndarray]:
    """The degraded-touch probe (docs/premise.md, "Reading episodes"): judge scores on `split`
    with each pair's touch replaced by another pair's (a derangement), for the baseline, the
    `paper` system (RA-Touch on the joint query), the `gated` system and the reader alone
    (`_gated_scores`) with their own and with shuffled neighbours, and a copy of the image
    query's top-1 caption."""
    bad = dataclasses.replace(split, T=split.T[derangement(len(split.T), seed + 101)])
    image_top = retrieve(p, bad.V, bad.T, 1, "image")[:, 0]
    copy_top = [p.corpus.entries[int(i)].caption for i in image_top]
    return {"baseline": answer_split(p, bad, BASELINE, judge=judge).scores,
            "paper": answer_split(p, bad, RA_TOUCH, k=k, judge=judge, name="paper").scores,
            "copy_image_top1": judge_answers(judge, bad, copy_top, "copy_image_top1")[0],
            **_gated_scores(p, bad, k, judge, seed)}


def summarise_withheld(results: list[dict[str, np.ndarray]], seed: int = 0) -> dict:
    """The degraded-touch probe over runs: each system's mean score, and the `paper` and
    `gated` systems' gains over the baseline and the gated shuffle drop, with pooled CIs."""
    out: dict = {"n": len(results[0]["baseline"]),
                 "score": {name: round(float(np.mean([r[name].mean() for r in results])), 4)
                           for name in results[0]}}
    pairs = [("paper_gain", "paper", "baseline"), ("gated_gain", "gated", "baseline"),
             ("gated_shuffle_drop", "gated", "gated_shuffled")]
    if "reader" in results[0]:
        pairs += [("reader_gain", "reader", "baseline"),
                  ("reader_shuffle_drop", "reader", "reader_shuffled")]
    for name, a, b in pairs:
        diffs = [r[a] - r[b] for r in results]
        out[name] = {"diff": round(float(np.mean([d.mean() for d in diffs])), 4),
                     "ci95": [round(x, 4) for x in pooled_ci(diffs, seed)],
                     "p": _p_value(diffs)}
    return out


def mode_precision(p: RATouchPipeline, split: TestSplit, k: int) -> dict[str, float]:
    """Material P@k of every query mode against the caption index on a split."""
    entry_mats = np.asarray([e.material for e in p.corpus.entries])
    mats = np.asarray(split.materials)
    out = {}
    for m in QUERY_MODES:
        ids = p.corpus.search("text", mode_query(m, split.V, split.T, p.joint_query), k)[1]
        out[m] = round(float((entry_mats[ids] == mats[:, None]).mean()), 4)
    return out


def run_premise(encoder: str = "default-s", runs: int = 3, n: int = 500, k: int = 5,
                progress: Progress = False,
                pipeline: RATouchPipeline | None = None, arm: bool = True,
                gated: bool = True, arms: tuple[str, ...] = tuple(ARMS),
                lm: str | None = None) -> dict:
    """Baseline against RA-Touch on seen and scarce materials, over `runs` runs, with controls.

    `pipeline`: the loaded retrieval side to use (default: `RATouchPipeline.load(encoder)`, on
    the default 10k corpus). `arm`: also train (on first use) and judge the second-stage arms
    named in `arms` (`ARMS`): the neighbour-token arm, which bounds what retrieval can deliver
    (`neighbour_tokens` per group), and the text arm, the neighbours' captions in the prompt
    (`neighbour_text` per group, and `arms_test`: the arms on the world test split).
    `gated`: also judge the `gated` system, the shipped RA-Touch reading the trust-gated
    query (`gated` per group, with its own verdict, `gated_verdict`), and report every
    mode's material P@k per group (`precision`). `lm`: on the generators adapted from that
    pretrained language model (`ratouch train generator --lm`): one run only
    (`check_lm_runs`), and no `gated` system (its reader exists on the small decoder only).

    Returns:
        {"config", "scarce_materials", "groups": {group: {"baseline", "ra_touch", "gain",
        "ci95", "ci95_runs", "shuffle_drop", "shuffle_p", "copy_ceiling", "copy_captions",
        "material_oracle", "integrator_zeroed", "f1", "length", "runs": [...]}}, "verdict",
        "verdict_reason", "seconds"}
    """
    if runs < 1 or n < 10 or k < 1:
        raise ConfigError(f"runs={runs} must be >= 1, n={n} >= 10 and k={k} >= 1")
    unknown = sorted(set(arms) - set(ARMS))
    if unknown:
        raise ConfigError(f"unknown arm(s) {unknown}: choose from {sorted(ARMS)}")
    arms = arms if arm else ()
    check_lm_runs(lm, runs)
    gated = gated and lm is None
    t0 = time.perf_counter()
    regime = ScarceRegime()
    say, progress = say_to(progress, log), bars(progress)  # lines; the training's bars
    pipe = pipeline or RATouchPipeline.load(encoder, progress=progress, generators=False)
    splits = {g: group_split(pipe.encoders, g, n, regime) for g in GROUPS}
    say(f"rendered and encoded {n} seen and {n} scarce pairs")
    judge = OfflineJudge()
    per_run: dict[str, list[dict]] = {g: [] for g in GROUPS}
    # the degraded-touch probe: the world test split (its first n pairs where n is smaller)
    test = (encode_test_split(pipe.encoders, indices=range(min(n, TEST_SIZE)))
            if gated or arms else None)
    withheld: list[dict[str, np.ndarray]] = []
    on_test: list[dict[str, np.ndarray]] = []
    for run in range(runs):
        ra, base = run_generators(encoder, run, progress, lm)
        trained = {name: ARMS[name](encoder, run, progress, lm) for name in arms}
        p = RATouchPipeline(pipe.retriever, pipe.tgr, ra, base, pca=pipe.pca, trust=pipe.trust,
                            gate=pipe.gate,
                            generator_reader=reader(encoder, run, progress) if gated else None,
                            lm=lm)
        for g in GROUPS:
            r = run_controls(p, k=k, shuffles=1, judge=judge, seed=run, split=splits[g],
                             keep_scores=True)
            if trained:
                r["scores"].update(_arm_scores(p, trained, splits[g], k, judge, seed=run))
            if gated:
                r["scores"].update(_gated_scores(p, splits[g], k, judge, seed=run))
            per_run[g].append(r)
            say(f"run {run} {g}: baseline {r['systems']['baseline']['mean']:.3f}, RA-Touch "
                f"{r['systems']['ra_touch']['mean']:.3f}, shuffle drop "
                f"{r['shuffle']['diff']:+.3f}")
        if test is not None and trained:
            on_test.append(arms_on_test(p, trained, test, k, judge))
            say(f"run {run} world test split: " + ", ".join(
                f"{m} {v.mean():.3f}" for m, v in on_test[-1].items()))
        if test is not None and gated:
            withheld.append(touch_withheld_scores(p, test, k, judge, seed=run))
            say(f"run {run} touch withheld: baseline {withheld[-1]['baseline'].mean():.3f}, "
                f"paper {withheld[-1]['paper'].mean():.3f}, gated "
                f"{withheld[-1]['gated'].mean():.3f}")
    groups = {g: _aggregate(per_run[g], seed=0) for g in GROUPS}
    verdict, reason = decide(groups)
    extra: dict = {}
    if gated:
        extra["precision"] = {g: mode_precision(pipe, splits[g], k) for g in GROUPS}
        extra["gated_verdict"], extra["gated_verdict_reason"] = decide_gated(groups)
        extra["touch_withheld"] = summarise_withheld(withheld)
    if on_test:
        extra["arms_test"] = summarise_test(on_test)
    return {**extra, "config": {"encoder": encoder, "lm": lm, "runs": runs, "n": n, "k": k, "judge": judge.name,
                       "regime": regime.tag, "draws": list(range(runs)), "arms": list(arms),
                       "seeds": list(range(runs))},
            "scarce_materials": list(regime.scarce_materials()), "groups": groups,
            "verdict": verdict, "verdict_reason": reason,
            "seconds": round(time.perf_counter() - t0, 1)}


def _aggregate(results: list[dict], seed: int) -> dict:
    """One group's figures over runs: means over runs, the gain's pooled CI (runs resampled,
    then samples within each) and its t interval across runs, the shuffle drop's p-value."""
    def mean_of(name: str, key: str = "mean") -> float:
        return round(float(np.mean([r["systems"][name][key] for r in results])), 4)

    gains = [r["scores"]["ra_touch"] - r["scores"]["baseline"] for r in results]
    drops = [r["scores"]["ra_touch"] - r["scores"]["shuffled_0"] for r in results]
    run_gain = np.array([g.mean() for g in gains])
    lo, hi = pooled_ci(gains, seed)
    if len(run_gain) > 1:
        half = stats.t.ppf(0.975, len(run_gain) - 1) * run_gain.std(ddof=1) / np.sqrt(len(run_gain))
        runs_ci = [round(float(run_gain.mean() - half), 4), round(float(run_gain.mean() + half), 4)]
    else:
        runs_ci = None
    p = _p_value(drops)
    names = ("baseline", "ra_touch", "neighbours_shuffled", "integrator_zeroed",
             "copy_captions", "copy_perfect_retrieval", "material_oracle")
    arm, text, gated, read = (_arm_summary(results, name, seed) if name in results[0]["scores"]
                              else None for name in ("tokens", "text", "gated", "reader"))
    return {
        "gated": gated, "reader": read, "neighbour_text": text,
        "n": results[0]["n"], "baseline": mean_of("baseline"), "ra_touch": mean_of("ra_touch"),
        "gain": round(float(run_gain.mean()), 4), "ci95": [round(lo, 4), round(hi, 4)],
        "ci95_runs": runs_ci,
        "shuffle_drop": round(float(np.mean([d.mean() for d in drops])), 4),
        "shuffle_drop_ci95": [round(x, 4) for x in pooled_ci(drops, seed)],
        "shuffle_p": p,
        "shuffle_changed_share": round(float(np.mean([r["shuffle"]["changed_share"]
                                                      for r in results])), 4),
        "integrator_zeroed": mean_of("integrator_zeroed"),
        "copy_captions": mean_of("copy_captions"),
        "copy_ceiling": mean_of("copy_perfect_retrieval"),
        "material_oracle": mean_of("material_oracle"),
        "f1": {s: mean_of(s, "f1") for s in names},
        "length": {s: mean_of(s, "mean_length") for s in names},
        "neighbour_tokens": arm,
        "reading": [r["reading"] for r in results],
        "runs": [{"baseline": round(r["systems"]["baseline"]["mean"], 4),
                  "ra_touch": round(r["systems"]["ra_touch"]["mean"], 4),
                  "gain": r["paired_vs_baseline"]["ra_touch"],
                  "shuffle_drop": {k: r["shuffle"][k] for k in ("diff", "ci_low", "ci_high")},
                  "copy_ceiling": round(r["systems"]["copy_perfect_retrieval"]["mean"], 4)}
                 for r in results],
    }


def _arm_summary(results: list[dict], name: str, seed: int) -> dict:
    """An arm's figures over runs (its scores `name` and `name`_shuffled): mean score, gain
    over the baseline with its pooled CI, its difference to the paper's RA-Touch on the same
    pairs (`vs_paper`) with its pooled CI, shuffle drop with its pooled CI and p, per-run
    gains."""
    gains = [r["scores"][name] - r["scores"]["baseline"] for r in results]
    drops = [r["scores"][name] - r["scores"][f"{name}_shuffled"] for r in results]
    vs_paper = [r["scores"][name] - r["scores"]["ra_touch"] for r in results]
    return {"vs_paper": round(float(np.mean([a.mean() for a in vs_paper])), 4),
            "vs_paper_ci95": [round(x, 4) for x in pooled_ci(vs_paper, seed)],
            "score": round(float(np.mean([r["scores"][name].mean() for r in results])), 4),
            "gain": round(float(np.mean([a.mean() for a in gains])), 4),
            "ci95": [round(x, 4) for x in pooled_ci(gains, seed)],
            "shuffle_drop": round(float(np.mean([a.mean() for a in drops])), 4),
            "shuffle_drop_ci95": [round(x, 4) for x in pooled_ci(drops, seed)],
            "shuffle_p": _p_value(drops),
            "runs": [round(float(a.mean()), 4) for a in gains]}


def _p_value(diffs: list[np.ndarray]) -> float:
    """Two-sided p of a one-sample t-test that the paired differences of all runs average 0
    (1.0 when they are all equal)."""
    d = np.concatenate(diffs)
    return float(stats.ttest_1samp(d, 0.0).pvalue) if d.std() > 0 else 1.0


def pooled_ci(diffs: list[np.ndarray], seed: int = 0, n_boot: int = 4000
              ) -> tuple[float, float]:
    """95 % CI of the mean of per-run means, resampling runs and then samples in each."""
    rng = np.random.default_rng(seed)
    runs = len(diffs)
    out = np.empty(n_boot)
    for b in range(n_boot):
        pick = rng.integers(0, runs, runs)
        out[b] = np.mean([diffs[i][rng.integers(0, len(diffs[i]), len(diffs[i]))].mean()
                          for i in pick])
    lo, hi = np.quantile(out, [0.025, 0.975])
    return float(lo), float(hi)


def decide(groups: dict) -> tuple[str, str]:
    """The pre-registered verdict (docs/premise.md) from the aggregated groups."""
    s, seen = groups["scarce"], groups["seen"]
    lo, hi = s["ci95"]
    headroom = s["copy_ceiling"] - s["baseline"]
    if lo > 0 and s["shuffle_p"] < 0.01 and s["shuffle_drop"] > 0 and s["gain"] > seen["gain"]:
        return "supported", (f"on scarce materials RA-Touch gains {s['gain']:+.3f} "
                             f"[{lo:+.3f}, {hi:+.3f}], shuffling its neighbours costs "
                             f"{s['shuffle_drop']:+.3f} (p = {s['shuffle_p']:.2g}), and the gain "
                             f"exceeds the seen materials' ({seen['gain']:+.3f})")
    if headroom >= COPY_MARGIN and s["gain"] < MIN_GAIN and hi < PAPER_EFFECT:
        return "refuted", (f"the copy ceiling is {headroom:+.3f} above the baseline on scarce "
                           f"materials, yet RA-Touch gains only {s['gain']:+.3f} "
                           f"[{lo:+.3f}, {hi:+.3f}], excluding the paper's +{PAPER_EFFECT}")
    why = (f"the copy ceiling is only {headroom:+.3f} above the baseline on scarce materials "
           f"(< +{COPY_MARGIN}): the corpus has little to give here"
           if headroom < COPY_MARGIN else
           f"RA-Touch's gain on scarce materials is {s['gain']:+.3f} [{lo:+.3f}, {hi:+.3f}] "
           f"(shuffle drop {s['shuffle_drop']:+.3f}, p = {s['shuffle_p']:.2g}; seen "
           f"{seen['gain']:+.3f}), meeting neither criterion")
    return "inconclusive", why


def decide_gated(groups: dict) -> tuple[str, str]:
    """The `gated` system's verdict by the criteria fixed before its first run (docs/premise.md,
    "Trust-gated retrieval"), on the premise groups (the world test split's >= 7.60 is
    measured apart, by `ratouch eval tvl`)."""
    s, seen = groups["scarce"]["gated"], groups["seen"]["gated"]
    lo, hi = s["ci95"]
    seen_lo, seen_hi = seen["ci95"]
    if s["gain"] >= PAPER_EFFECT and lo > 0 and s["shuffle_p"] < 0.01 \
            and s["shuffle_drop"] > 0 and seen["gain"] >= -0.05:
        return "supported", (f"on scarce materials gated gains {s['gain']:+.3f} [{lo:+.3f}, "
                             f"{hi:+.3f}], shuffling costs {s['shuffle_drop']:+.3f} "
                             f"(p = {s['shuffle_p']:.2g}), seen {seen['gain']:+.3f}")
    if hi < PAPER_EFFECT or seen_hi < -0.05:
        return "refuted", (f"on scarce materials gated gains {s['gain']:+.3f} [{lo:+.3f}, "
                           f"{hi:+.3f}] (the criterion: >= +{PAPER_EFFECT}); seen "
                           f"{seen['gain']:+.3f} [{seen_lo:+.3f}, {seen_hi:+.3f}]; shuffle drop "
                           f"{s['shuffle_drop']:+.3f} (p = {s['shuffle_p']:.2g})")
    return "inconclusive", (f"gated's scarce gain {s['gain']:+.3f} [{lo:+.3f}, {hi:+.3f}], "
                            f"shuffle drop {s['shuffle_drop']:+.3f} (p = {s['shuffle_p']:.2g}), "
                            f"seen {seen['gain']:+.3f}: neither criterion met")


def format_premise(r: dict) -> str:
    """The premise's figures as a table, then the verdict."""
    c = r["config"]
    on = f" on the generators of {c['lm']}" if c.get("lm") else ""
    lines = [f"the premise on the world{on} ({c['runs']} runs: seeds and draws {c['seeds']}; "
             f"{c['n']} pairs per group; K={c['k']}; judge {c['judge']}; regime {c['regime']})",
             f"scarce materials: {', '.join(r['scarce_materials'])}",
             f"{'group':<8}{'baseline':>9}{'RA-Touch':>9}  {'gain [pooled 95% CI]':<26}"
             f"{'shuffle drop (p)':<22}{'zeroed':>8}{'copy':>8}{'copy ceil':>10}{'oracle':>8}"
             f"  F1 base/RA  length base/RA"]
    for g in GROUPS:
        s = r["groups"][g]
        lines.append(
            f"{g:<8}{s['baseline']:>9.3f}{s['ra_touch']:>9.3f}  "
            f"{s['gain']:+.3f} [{s['ci95'][0]:+.3f}, {s['ci95'][1]:+.3f}]{'':<5}"
            f"{s['shuffle_drop']:+.3f} (p={s['shuffle_p']:.1g}){'':<6}"
            f"{s['integrator_zeroed']:>8.3f}{s['copy_captions']:>8.3f}{s['copy_ceiling']:>10.3f}"
            f"{s['material_oracle']:>8.3f}  {s['f1']['baseline']:.3f}/{s['f1']['ra_touch']:.3f}"
            f"  {s['length']['baseline']:.1f}/{s['length']['ra_touch']:.1f}")
        a = s.get("neighbour_tokens")
        if a:
            lines.append(f"  second arm (neighbour tokens, not the paper's method): {a['score']:.3f}, "
                         f"gain {a['gain']:+.3f} [{a['ci95'][0]:+.3f}, {a['ci95'][1]:+.3f}], "
                         f"shuffle drop {a['shuffle_drop']:+.3f} (p={a['shuffle_p']:.1g})")
        t = s.get("neighbour_text")
        if t:
            lines.append(f"  text arm (the neighbours' captions in the prompt): {t['score']:.3f}, "
                         f"gain {t['gain']:+.3f} [{t['ci95'][0]:+.3f}, {t['ci95'][1]:+.3f}], "
                         f"shuffle drop {t['shuffle_drop']:+.3f} (p={t['shuffle_p']:.1g}), "
                         f"text - paper {t['vs_paper']:+.3f} [{t['vs_paper_ci95'][0]:+.3f}, "
                         f"{t['vs_paper_ci95'][1]:+.3f}]")
        for key, title in (("gated", "gated (trust-routed, on the gated query)"),
                           ("reader", "the reader alone (on the gated query)")):
            gt = s.get(key)
            if gt:
                lines.append(f"  {title}: {gt['score']:.3f}, gain {gt['gain']:+.3f} "
                             f"[{gt['ci95'][0]:+.3f}, {gt['ci95'][1]:+.3f}], shuffle drop "
                             f"{gt['shuffle_drop']:+.3f} (p={gt['shuffle_p']:.1g})")
        if r.get("precision"):
            lines.append("  material P@k: " + ", ".join(
                f"{m} {v:.3f}" for m, v in r["precision"][g].items()))
        for i, run in enumerate(s["runs"]):
            gd = run["gain"]
            lines.append(f"  run {i}: baseline {run['baseline']:.3f}, RA-Touch "
                         f"{run['ra_touch']:.3f}, gain {gd['diff']:+.3f} [{gd['ci_low']:+.3f}, "
                         f"{gd['ci_high']:+.3f}], shuffle drop {run['shuffle_drop']['diff']:+.3f}")
    tw = r.get("touch_withheld")
    if tw:
        sc = tw["score"]
        lines.append(f"touch withheld (world test split, each pair read with another's touch; "
                     f"n={tw['n']}): " + ", ".join(f"{m} {v:.3f}" for m, v in sc.items()))
        for key in ("paper_gain", "gated_gain", "gated_shuffle_drop", "reader_gain",
                    "reader_shuffle_drop"):
            if key not in tw:
                continue
            d = tw[key]
            lines.append(f"  {key.replace('_', ' ')}: {d['diff']:+.3f} [{d['ci95'][0]:+.3f}, "
                         f"{d['ci95'][1]:+.3f}] (p={d['p']:.1g})")
    at = r.get("arms_test")
    if at:
        lines.append(f"world test split (n={at['n']}, the paper's neighbours): " + ", ".join(
            f"{m} {v:.3f}" for m, v in at["score"].items()))
        for key, d in at.items():
            if key.endswith(("_vs_baseline", "_vs_paper")):
                lines.append(f"  {key.replace('_', ' ')}: {d['diff']:+.3f} [{d['ci95'][0]:+.3f}, "
                             f"{d['ci95'][1]:+.3f}] (p={d['p']:.1g})")
    lines.append(f"verdict: {r['verdict']}: {r['verdict_reason']} ({r['seconds']:.0f} s)")
    if r.get("gated_verdict"):
        lines.append(f"gated verdict: {r['gated_verdict']}: {r['gated_verdict_reason']}")
    return "\n".join(lines)


def why_ignored(encoder: str = "default-s", n: int = 3000, seed: int = 0,
                pipeline: RATouchPipeline | None = None, n_pairs: int | None = None) -> dict:
    """Evidence for why a RA-Touch generator does (not) read its neighbours, on its own paired
    training data (draw 0, the first `n` pairs): what the neighbours could teach it there, and
    how much its training signal depends on them.

    * **What reading would earn in training**: label-adjective F1 of the baseline's answers and
      of a vote over each pair's retrieved captions (length-matched), on head and on scarce
      materials, and the share of training pairs that are scarce. Where the vote is far worse
      than the baseline, the best policy on those pairs is to ignore the neighbours.
    * **Gradient signal**: at the start of stage 2 (zero-initialised integrator, fresh LoRA on
      the shipped stage-1 model) and at its end (the shipped RA-Touch), the cosine between the
      integrator's loss gradient with the pairs' own and with shuffled neighbours, and the
      relative size of their difference: near 1 and near 0 mean the gradient does not care
      which neighbours it reads.
    * **Training loss**: the shipped RA-Touch's loss with own, shuffled and no neighbours.

    `n_pairs` reads only the first pairs of the paired split (None: all 12,000); the shares
    and F1s are then of that part.
    """
    pipe = pipeline or RATouchPipeline.load(encoder)
    data = training_pairs(pipe.encoders, seed=0, n_pairs=n_pairs)
    scarce = set(ScarceRegime().scarce_materials())
    pick = np.random.default_rng(seed).permutation(len(data["labels"]))[:n]
    is_scarce = np.array([data["materials"][i] in scarce for i in range(len(data["labels"]))])
    # every scarce pair, and head pairs up to n
    pick = np.concatenate([np.flatnonzero(is_scarce), pick[~is_scarce[pick]]])
    V, T = data["V"][pick], data["T"][pick]
    labels = [data["labels"][i] for i in pick]
    sc = is_scarce[pick]
    ids = pipe.joint_neighbours(V, T, 5)
    rv, rl = pipe.neighbour_embeddings(ids)
    pairs = SimpleNamespace(V=V, T=T)
    base = answer_split(pipe, pairs, BASELINE).responses
    ra = answer_split(pipe, pairs, RA_TOUCH, neighbours=(rv, rl)).responses
    entries = pipe.corpus.entries
    copy_ = [vote([entries[i].caption for i in row], len(parse_adjectives(b)))
             for row, b in zip(ids, base)]

    def f1(answers, mask):
        return round(float(np.mean([adjective_f1(lab, a) for lab, a, m in
                                    zip(labels, answers, mask) if m])), 4)

    out = {"n_pairs": len(data["labels"]), "scarce_share": round(float(is_scarce.mean()), 4),
           "f1": {g: {"baseline": f1(base, m), "ra_touch": f1(ra, m), "copy_captions": f1(copy_, m)}
                  for g, m in (("head", ~sc), ("scarce", sc))}}
    # gradients and losses
    Vt, Tt = torch.from_numpy(V), torch.from_numpy(T)
    rvt, rlt = torch.from_numpy(rv), torch.from_numpy(rl)
    shuf = torch.from_numpy(derangement(len(V), seed))
    stage1 = load_generator(generator_weights(encoder, "ra"), stage1=True)
    start = copy.deepcopy(stage1)
    start.integrator = seeded_build(0, lambda: TextureAwareIntegrator(
        IntegratorConfig(dim=pipe.encoders.dim, out_dim=start.decoder.hidden)))
    start.decoder.add_lora(start.decoder.cfg, seed=0)
    end = load_generator(generator_weights(encoder, "ra"), integrator_factory)
    grads = {}
    for name, gen in (("start", start), ("end", end)):
        gen.train()
        integrator = gen.integrator
        assert integrator is not None  # both carry one: set on `start`, loaded with `end`
        params = [p for p in integrator.parameters()]
        for p in params:
            p.requires_grad_(True)
        g = []
        for nb in (torch.arange(len(V)), shuf):
            b = torch.arange(min(len(V), 512))
            loss = gen.loss(Vt[b], Tt[b], [labels[i] for i in b.tolist()], rvt[nb[b]], rlt[nb[b]])
            g.append(torch.cat([x.flatten() for x in torch.autograd.grad(loss, params)]))
        cos = torch.nn.functional.cosine_similarity(g[0], g[1], dim=0).item()
        grads[name] = {"cosine_own_vs_shuffled": round(cos, 4),
                       "relative_difference": round(((g[0] - g[1]).norm() / g[0].norm()).item(), 4)}
        gen.eval()
    out["integrator_gradient"] = grads
    losses = {}
    with torch.no_grad():
        for group, m in (("head", ~sc), ("scarce", sc)):
            b = torch.from_numpy(np.flatnonzero(m)[:512])
            lab = [labels[i] for i in b.tolist()]
            losses[group] = {
                "own": round(end.loss(Vt[b], Tt[b], lab, rvt[b], rlt[b]).item(), 4),
                "shuffled": round(end.loss(Vt[b], Tt[b], lab, rvt[shuf[b]],
                                           rlt[shuf[b]]).item(), 4),
                "none": round(end.loss(Vt[b], Tt[b], lab).item(), 4)}
    out["training_loss"] = losses
    return out
