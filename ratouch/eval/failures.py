"""Failure cases of RA-Touch on the world's test split, under a few named stress conditions.

For every (condition, test sample): the no-retrieval baseline's and RA-Touch's descriptions and
their offline-judge scores, and the material precision@K of the neighbours that each query mode
(`ratouch.search.modes.QUERY_MODES`) retrieves. Two questions are asked of the table:

- where does RA-Touch score lowest (and how far below the baseline, `ra_delta`)?
- where does the joint (Tactile-Guided Retriever) query retrieve worse neighbours than the best
  single-modality query (`joint_loses`)?

`load_or_compute` caches the table as JSON under ``cache_dir()/failures/`` keyed by the settings
and the asset manifests, so a second call (or the app) reads it at once; `case_sample` rebuilds
one case's inputs from (condition, index) so it can be queried again.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import logging
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Mapping, Sequence

import numpy as np

from ratouch.checkpoint import sha256_file
from ratouch.corpus.embed import EMBED_MANIFEST, embeddings_dir
from ratouch.errors import ConfigError, DataError
from ratouch.eval.answer import BASELINE, RA_TOUCH, answer_split, retrieve
from ratouch.eval.judge import OfflineJudge, mean_ci, score_stats
from ratouch.eval.retrieval import entry_materials, material_precision
from ratouch.files import write_json_atomic
from ratouch.paths import (
    cache_dir,
    encoder_weights,
    generator_weights,
    retriever_weights,
)
from ratouch.search.modes import QUERY_MODES, RA_TOUCH_MODE
from ratouch.serve.request import check_k
from ratouch.world.config import WorldConfig
from ratouch.world.dataset import world_for
from ratouch.world.sampler import TEST_SIZE, World
from ratouch.world.splits import encode_test_split

log = logging.getLogger(__name__)

FORMAT_VERSION = 1

# name -> stress knobs (`WorldConfig.with_stress`), applied on top of the given world
CONDITIONS: dict[str, dict[str, Any]] = {
    "natural": {},
    "small object + dominant background": {"object_scale": 0.12, "background_dominance": 1.0,
                                           "clutter": 4},
    "noisy touch": {"tactile_noise": 0.2},
    "box offset": {"box_offset": 1.0},
}
DEFAULT_CONDITIONS = tuple(CONDITIONS)
MODES = QUERY_MODES
SUBSETS = ("structured", "wild")
# view name -> what it shows
VIEWS = {"ra_lowest": "RA-Touch scores lowest",
         "joint_loses": "joint query loses to a unimodal one"}
# a row's descriptions and the keys of their judge scores
SCORE_KEYS = {"baseline": "baseline_score", "ra_touch": "ra_score"}
SCORE_DIGITS = 3  # judge scores are kept (in the table, in a case's view) to 3 decimals

Progress = Callable[[float, str], Any]


# --------------------------------------------------------------------------- conditions

def condition_world(world: WorldConfig | None, condition: str) -> WorldConfig:
    """The world config of a named condition (its stress knobs over `world`'s)."""
    if condition not in CONDITIONS:
        raise ConfigError(f"unknown condition {condition!r}; known: {', '.join(CONDITIONS)}")
    return (world or WorldConfig()).with_stress(**CONDITIONS[condition])


def case_world(condition: str, world: WorldConfig | None = None) -> World:
    """The world a condition renders its cases in (the base world with its stress knobs)."""
    return world_for(condition_world(world, condition))


def case_sample(condition: str, index: int, world: WorldConfig | None = None):
    """The test sample `index` of a condition's world (a `ratouch.world.sampler.Sample`):
    its `.visual`, `.tactile`, `.box` and `.caption` are one failure case's query inputs,
    with its sensor's background (`case_world(...).background_image(sample.sensor)`)."""
    try:
        i = int(index)
    except (TypeError, ValueError) as e:
        raise DataError(f"test index must be an integer, got {index!r}") from e
    if not 0 <= i < TEST_SIZE:
        raise DataError(f"test index {i} is out of range 0..{TEST_SIZE - 1}")
    return case_world(condition, world).sample("test", i)


# --------------------------------------------------------------------------- judging

def row_scores(row: Mapping[str, Any]) -> dict[str, tuple[str | None, float]]:
    """The descriptions a table row's judge scores belong to: {system: (description, score)}
    for "baseline" and "ra_touch" (`judge_scores`' `judged`)."""
    return {name: (row.get(name), float(row[key])) for name, key in SCORE_KEYS.items()
            if key in row}


def judge_scores(label: str | None, descriptions: Mapping[str, str | None], judge,
                 judged: Mapping[str, tuple[str | None, float]] | None = None
                 ) -> dict[str, float | None]:
    """Offline-judge score (1-10) of each description against the ground-truth label.

    Args:
        judged: {name: (description, score)} already judged, e.g. a failure-table row's
            (`row_scores`): a description equal to its judged one gets that score, so that a
            case shows one score wherever it is shown. (The table judges each system's answers
            together, with the system's word rates, `OfflineJudge.score_many`; a lone answer
            judged here has no rates to go by.)

    Returns {} without a label; a description that is missing or empty scores None (it was
    not generated), not the judge's 1."""
    if not label:
        return {}
    judged = judged or {}
    out: dict[str, float | None] = {}
    for name, text in descriptions.items():
        if not text:
            out[name] = None
        elif name in judged and judged[name][0] == text:
            out[name] = round(float(judged[name][1]), SCORE_DIGITS)
        else:
            out[name] = round(judge.score(label, text), SCORE_DIGITS)
    return out


# --------------------------------------------------------------------------- computing

def failure_cases(pipeline, world: WorldConfig | None = None, k: int = 5,
                  conditions: Sequence[str] = DEFAULT_CONDITIONS,
                  indices: Sequence[int] | None = None, judge=None,
                  progress: Progress | None = None) -> list[dict]:
    """One row per (condition, test sample) with descriptions, scores and retrieval quality.

    Args:
        pipeline: a loaded `RATouchPipeline` (encoders, corpus, retriever, both generators).
        world: the base world (default: seed 0, no stress); each condition adds its knobs.
        k: neighbours per query (RA-Touch reads the joint query's K neighbours).
        conditions: names from `CONDITIONS`.
        indices: test-split indices (default: all 402).
        judge: scores descriptions (default: the offline judge).
        progress: called as progress(fraction, what) between steps.

    Returns:
        Rows {"condition", "index", "subset", "material", "object_scale", "label",
        "baseline", "ra_touch", "baseline_score", "ra_score", "ra_delta",
        "precision_<mode>" per query mode (`QUERY_MODES`), "best_unimodal", "joint_gap",
        "joint_loses"}; precisions are material precision@K of each mode's neighbours,
        `joint_gap` = the best other mode's precision - that of the mode RA-Touch reads.
    """
    conditions = _check_conditions(conditions)
    k = check_k(k, len(pipeline.corpus.entries))
    judge = judge or OfflineJudge()
    entry_mats = entry_materials(pipeline.corpus)
    if not entry_mats.size or not all(entry_mats):
        raise DataError("the corpus entries carry no material: failure cases need a world "
                        "corpus (ImageNet-T built from the procedural world)")
    steps, done = 4 * len(conditions), 0

    def step(what: str) -> None:
        nonlocal done
        if progress is not None:
            progress(done / steps, what)
        done += 1

    rows: list[dict] = []
    for cond in conditions:
        step(f"{cond}: rendering and encoding the test split")
        split = encode_test_split(pipeline.encoders, condition_world(world, cond), indices)
        step(f"{cond}: baseline descriptions")
        base = answer_split(pipeline, split, BASELINE, judge=judge)
        step(f"{cond}: RA-Touch descriptions")
        ra = answer_split(pipeline, split, RA_TOUCH, k=k, judge=judge)
        step(f"{cond}: retrieval quality and judging")
        assert ra.ids is not None  # RA-Touch read the joint query's neighbours
        prec = {mode: material_precision(ra.ids if mode == RA_TOUCH_MODE else
                                         retrieve(pipeline, split.V, split.T, k, mode),
                                         split.materials, entry_mats) for mode in MODES}
        s_base, s_ra = base.scores, ra.scores
        for j, idx in enumerate(split.indices):
            # the best single-sense query (the modes the retriever does not make)
            best = max(float(prec[m][j]) for m in MODES if "retriever" not in MODES[m].needs)
            pj = float(prec[RA_TOUCH_MODE][j])
            rows.append({
                "condition": cond, "index": int(idx), "subset": split.subsets[j],
                "material": split.materials[j], "object_scale": round(split.object_scale[j], 3),
                "label": split.labels[j], "baseline": base.responses[j],
                "ra_touch": ra.responses[j],
                "baseline_score": round(float(s_base[j]), SCORE_DIGITS),
                "ra_score": round(float(s_ra[j]), SCORE_DIGITS),
                "ra_delta": round(float(s_ra[j]) - float(s_base[j]), SCORE_DIGITS),
                **{f"precision_{m}": round(float(prec[m][j]), 4) for m in MODES},
                "best_unimodal": round(best, 4), "joint_gap": round(best - pj, 4),
                "joint_loses": bool(pj < best)})
    if progress is not None:
        progress(1.0, "done")
    return rows


def _check_conditions(conditions: Iterable[str]) -> tuple[str, ...]:
    out = tuple(dict.fromkeys(conditions))
    if not out:
        raise ConfigError("give at least one condition")
    unknown = [c for c in out if c not in CONDITIONS]
    if unknown:
        raise ConfigError(f"unknown condition(s) {unknown}; known: {', '.join(CONDITIONS)}")
    return out


# --------------------------------------------------------------------------- the cache

def _file_digest(path: Path) -> str | None:
    return sha256_file(path) if path.is_file() else None


def asset_manifests(pipeline) -> dict[str, str | None]:
    """sha256 of every manifest the table depends on: encoder, retriever and generator
    weights, the corpus and its embeddings (None for one that does not exist)."""
    enc = pipeline.encoders.name
    files = {f"encoders/{enc}": encoder_weights(enc) / "manifest.json",
             f"retriever/{enc}": retriever_weights(enc) / "manifest.json",
             f"generator/{enc}/ra": generator_weights(enc, "ra") / "manifest.json",
             f"generator/{enc}/baseline": generator_weights(enc, "baseline") / "manifest.json"}
    out = {name: _file_digest(p) for name, p in files.items()}
    corpus = pipeline.corpus
    out["corpus"] = (getattr(corpus, "manifest", None) or {}).get("metadata_sha256")
    folder = getattr(corpus, "folder", None)
    if folder is not None:

        out["embeddings"] = _file_digest(embeddings_dir(folder, enc) / EMBED_MANIFEST)
    return out


def settings(pipeline, world: WorldConfig | None = None, k: int = 5,
             conditions: Sequence[str] = DEFAULT_CONDITIONS,
             indices: Sequence[int] | None = None) -> dict:
    """Everything a cached table depends on (its key is a hash of this)."""
    conditions = _check_conditions(conditions)
    return {"version": FORMAT_VERSION, "encoder": pipeline.encoders.name, "k": int(k),
            "world": asdict(world or WorldConfig()),
            "conditions": {c: CONDITIONS[c] for c in conditions},
            "indices": None if indices is None else [int(i) for i in indices],
            "corpus_size": len(pipeline.corpus.entries),
            "judge": OfflineJudge().params, "assets": asset_manifests(pipeline),
            "modes": list(MODES)}


def cache_path(pipeline, world: WorldConfig | None = None, k: int = 5,
               conditions: Sequence[str] = DEFAULT_CONDITIONS,
               indices: Sequence[int] | None = None) -> Path:
    """``cache_dir()/failures/<encoder>-<hash of settings and asset manifests>.json``."""
    key = json.dumps(settings(pipeline, world, k, conditions, indices), sort_keys=True,
                     default=str)
    digest = hashlib.sha256(key.encode()).hexdigest()[:16]
    return cache_dir() / "failures" / f"{pipeline.encoders.name}-{digest}.json"


def load_cached(path: str | Path) -> dict | None:
    """A cached table ({"rows", "meta"}), or None if there is none (or it is unreadable)."""
    path = Path(path)
    if not path.is_file():
        return None
    try:
        table = json.loads(path.read_text(encoding="utf-8"))
        if table.get("meta", {}).get("version") != FORMAT_VERSION or \
                not isinstance(table.get("rows"), list):
            raise ValueError("unexpected layout")
    except (OSError, ValueError, AttributeError) as e:
        log.warning("ignoring unreadable failure-case cache %s: %s", path, e)
        return None
    return table


@contextlib.contextmanager
def _exclusive(path: Path) -> Iterator[None]:
    """Hold an exclusive lock on ``<path>.lock`` (between threads and processes alike)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path.with_name(path.name + ".lock"), "a") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def load_or_compute(pipeline, world: WorldConfig | None = None, k: int = 5,
                    conditions: Sequence[str] = DEFAULT_CONDITIONS,
                    indices: Sequence[int] | None = None, progress: Progress | None = None,
                    cached_only: bool = False, refresh: bool = False) -> dict | None:
    """The failure-case table for these settings: read from the cache, else computed and
    cached. Threads (and processes) asking for the same table compute it once.

    Args:
        cached_only: return None instead of computing when nothing is cached.
        refresh: recompute even if a cached table exists.

    Returns:
        {"rows": [...] (see `failure_cases`), "meta": {settings..., "seconds", "computed_at",
        "path"}} or None (cached_only and nothing cached).
    """
    path = cache_path(pipeline, world, k, conditions, indices)
    if not refresh and (table := load_cached(path)) is not None:
        return table
    if cached_only:
        return None
    with _exclusive(path):
        if not refresh and (table := load_cached(path)) is not None:
            return table  # another thread computed it while this one waited

        t0 = time.perf_counter()
        rows = failure_cases(pipeline, world, k, conditions, indices, progress=progress)
        meta = settings(pipeline, world, k, conditions, indices)
        meta.update({"seconds": round(time.perf_counter() - t0, 1),
                     "computed_at": time.strftime("%Y-%m-%d %H:%M:%S"), "path": str(path),
                     "n_rows": len(rows)})
        table = {"meta": meta, "rows": rows}
        write_json_atomic(path, table)
        log.info("failure cases: %d rows in %.0f s, cached in %s", len(rows), meta["seconds"],
                 path)
        return table


# --------------------------------------------------------------------------- reading the table

def select_cases(rows: Sequence[dict], subset: str = "all", condition: str = "all",
                 view: str = "ra_lowest", limit: int | None = 50) -> list[dict]:
    """The worst cases of a view, filtered by subset and condition ("all" keeps every one).

    Views:
        ra_lowest: by RA-Touch's judge score, lowest first (then the largest loss to the
            baseline).
        joint_loses: only cases whose joint query's material precision is below the best
            unimodal one, the largest gap first (then RA-Touch's score, lowest first).
    """
    if view not in VIEWS:
        raise ConfigError(f"view must be one of {list(VIEWS)}, got {view!r}")
    if subset not in ("all", *SUBSETS):
        raise ConfigError(f"subset must be 'all' or one of {SUBSETS}, got {subset!r}")
    if condition != "all" and condition not in CONDITIONS:
        raise ConfigError(f"unknown condition {condition!r}")
    out = [r for r in rows if (subset == "all" or r["subset"] == subset)
           and (condition == "all" or r["condition"] == condition)]
    if view == "ra_lowest":
        out.sort(key=lambda r: (r["ra_score"], r["ra_delta"], r["condition"], r["index"]))
    else:
        out = [r for r in out if r["joint_loses"]]
        out.sort(key=lambda r: (-r["joint_gap"], r["ra_score"], r["condition"], r["index"]))
    return out if limit is None else out[:int(limit)]


def summarise(rows: Sequence[dict]) -> list[dict]:
    """Per condition (in table order) and subset: n, mean baseline / RA-Touch score with their
    95 % bootstrap CIs, adjective F1 and mean length, RA-Touch's mean paired difference with
    its CI, mean material precision per mode, and the share of cases where the joint query
    loses."""
    groups: dict[tuple[str, str], list[dict]] = {}
    for r in rows:
        for sub in (r["subset"], "all"):
            groups.setdefault((r["condition"], sub), []).append(r)
    out: list[dict[str, Any]] = []
    for (cond, sub), rs in groups.items():
        if sub != "all" and len({r["subset"] for r in rows if r["condition"] == cond}) < 2:
            continue  # one subset only: its row would repeat "all"
        mean = lambda key, rs=rs: round(float(np.mean([r[key] for r in rs])), 3)  # noqa: E731
        labels = [r["label"] for r in rs]
        stats = {name: score_stats(labels, [r[name] for r in rs], [r[key] for r in rs])
                 for name, key in (("baseline", "baseline_score"), ("ra_touch", "ra_score"))}
        _, lo, hi = mean_ci([r["ra_delta"] for r in rs])
        out.append({"condition": cond, "subset": sub, "n": len(rs),
                    "baseline_score": mean("baseline_score"), "ra_score": mean("ra_score"),
                    "ra_delta": mean("ra_delta"), "ra_delta_ci": [round(lo, 3), round(hi, 3)],
                    **{f"{short}_{field}": (round(st["ci_low"], 3), round(st["ci_high"], 3))
                       if field == "ci" else round(st[field], 3)
                       for short, st in (("baseline", stats["baseline"]),
                                         ("ra", stats["ra_touch"]))
                       for field in ("ci", "f1", "mean_length")},
                    # a mode the rows do not hold (a table from before it was registered):
                    # None, not an error
                    **{f"precision_{m}": (mean(f"precision_{m}") if all(
                        f"precision_{m}" in r for r in rs) else None) for m in MODES},
                    "joint_loses": round(float(np.mean([r["joint_loses"] for r in rs])), 3)})
    order = {c: i for i, c in enumerate(dict.fromkeys(r["condition"] for r in rows))}
    sub_order = {"all": 0, "structured": 1, "wild": 2}
    out.sort(key=lambda s: (order[s["condition"]], sub_order[s["subset"]]))
    return out
