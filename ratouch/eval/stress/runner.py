"""The stress run: render the test samples under each knob's settings, answer and score every
point against its (paired) reference, find the break points, check for collapse.
"""

from __future__ import annotations

import copy
import logging
import time
from typing import Any, Callable, Sequence

import numpy as np

from ratouch.errors import ConfigError
from ratouch.eval.judge import OfflineJudge
from ratouch.eval.stress.collapse import collapse_report
from ratouch.eval.stress.scoring import Context, answers, break_points, scale_bins, score_point
from ratouch.eval.stress.sweeps import (
    DEFAULT_N,
    PAIR_FIXED,
    PER_SAMPLE,
    build_sweeps,
    stratified_indices,
)
from ratouch.serve.request import check_k
from ratouch.timing import Progress, say_to
from ratouch.world.config import StressConfig, WorldConfig
from ratouch.world.sampler import World
from ratouch.world.splits import TestSplit, encode_samples

log = logging.getLogger(__name__)


class _Renderer:
    """Test samples under any stress, sharing one World's texture caches (pyramids and
    sensor backgrounds depend only on pattern specs and the tactile size, never on stress)."""

    def __init__(self, world: WorldConfig):

        self.world = world
        self.base = World(world)

    def _world(self, knobs: dict):
        w = copy.copy(self.base)  # shallow: the caches are shared
        w.cfg = self.world.with_stress(**knobs)
        return w

    def natural_values(self, indices: Sequence[int]) -> dict[str, list]:
        """Each sample's natural value of the per-sample knobs (drawn, nothing rendered)."""
        size = self.world.image_size
        out: dict[str, list] = {k: [] for k in PER_SAMPLE}
        for i in indices:
            _, _, _, scene, touch, _, _ = self.base.plan("test", i)
            out["object_scale"].append(float(scene.object_scale / size))
            out["clutter"].append(len(scene.distractors))
            out["background_dominance"].append(float(scene.dominance))
            out["tactile_noise"].append(float(touch.noise))
            out["tactile_blur"].append(float(touch.blur))
        return out

    def split(self, encoders, indices: Sequence[int], knobs: dict | None = None,
              per_sample: Sequence[dict] | None = None) -> TestSplit:
        """Render and encode; `per_sample[j]` are extra knobs for sample j."""
        shared = self._world(knobs or {})
        worlds = [self._world({**(knobs or {}), **per_sample[j]}) if per_sample else shared
                  for j in range(len(indices))]
        samples = [w.sample("test", i) for w, i in zip(worlds, indices, strict=True)]
        return encode_samples(encoders, samples, worlds, indices, shared.cfg)


_NATURAL_LABEL = {"tactile_rotation": "0", "box_offset": "0", "missing": "none"}


def _label(knob: str, setting: dict | None, natural_mean: float | None) -> str:
    if setting is None:
        if knob in _NATURAL_LABEL:
            return _NATURAL_LABEL[knob]
        return "natural" if natural_mean is None else f"natural ({natural_mean:.3g})"
    if knob == "paper_failure":
        return "failure"
    v = setting[knob]
    return v if isinstance(v, str) else f"{v:g}"


def _x(knob: str, setting: dict | None, natural_mean: float | None):
    if knob in ("missing", "paper_failure"):
        return _label(knob, setting, None).split(" ")[0]
    if setting is None:
        return 0.0 if natural_mean is None else round(natural_mean, 4)
    return float(setting[knob])


def run_stress(pipeline, sweeps: dict[str, list[dict]] | None = None, k: int = 5,
               n: int | None = DEFAULT_N, world: WorldConfig | None = None, judge=None,
               collapse: bool = True, collapse_epochs: int = 12, encoder: str = "default-s",
               drop: float = 0.8, align_tgr=None,
               progress: Progress = None) -> dict:
    """Run the stress sweeps; returns the JSON-able result (see the module docstring).

    Args:
        pipeline: a loaded `RATouchPipeline` (encoders, corpus, retriever, generators).
        sweeps: `build_sweeps(...)` (default: every knob's default sweep).
        k: neighbours per query (precision@K, overlap@K; RA-Touch reads them).
        n: test samples (stratified over structured / wild); None = all 402.
        world: base world config (seed); its stress must be the default.
        judge: scorer with `score_many` (default the offline judge).
        collapse: also run the collapse diagnostic (trains an align-only retriever once).
        drop: break-point threshold as a fraction of the unperturbed value.
        align_tgr: an align-only retriever to compare with (skips loading/training it).
        progress: where a line per finished point goes (`ratouch.timing.Progress`); the
            collapse check's training shows bars when it is given.
    """

    t_start = time.perf_counter()
    sweeps = build_sweeps() if sweeps is None else sweeps
    k = check_k(k, len(pipeline.corpus))
    if not 0 < drop < 1:
        raise ConfigError(f"drop={drop} must lie in (0, 1)")
    world = world or WorldConfig()
    if world.stress != StressConfig():
        raise ConfigError("the base world of a stress sweep must be unstressed")
    say = say_to(progress, log)
    run = _Sweep(pipeline, Context(pipeline, k, judge or OfflineJudge()),
                 stratified_indices(n), world, say)
    nat_split, nat_ans = run.reference(())
    result: dict[str, Any] = {
        "encoder": encoder, "k": k, "n": len(run.indices), "world_seed": world.seed,
        "drop": drop, "indices": run.indices, "judge": type(run.ctx.judge).__name__,
        "natural_means": {kk: round(float(np.mean(v)), 4) for kk, v in run.natural.items()},
        "reference": {**score_point(nat_split, nat_ans, nat_split, nat_ans, run.ctx),
                      "scale_bins": scale_bins(nat_split, nat_ans, run.ctx)},
        "knobs": {knob: run.knob(knob, settings, drop) for knob, settings in sweeps.items()}}
    result["collapse"] = None
    if collapse:
        t0 = time.perf_counter()
        result["collapse"] = collapse_report(pipeline, nat_split, run.ctx, encoder,
                                             collapse_epochs, world.seed, align_tgr=align_tgr,
                                             progress=bool(progress))
        result["collapse"]["seconds"] = round(time.perf_counter() - t0, 1)
        say(f"collapse diagnostic: {result['collapse']['seconds']:.1f} s")
    result["seconds"] = round(time.perf_counter() - t_start, 1)
    return result


class _Sweep:
    """One stress run's shared state: the samples, their natural knob values, and the
    (paired) references computed once per set of paired knobs."""

    def __init__(self, pipeline, ctx: Context, indices: list[int], world: WorldConfig,
                 say: Callable[[str], None]):
        self.pipeline, self.ctx, self.indices, self.say = pipeline, ctx, indices, say
        self.renderer = _Renderer(world)
        self.natural = self.renderer.natural_values(indices)
        self.refs: dict[tuple, tuple[TestSplit, dict]] = {}

    def reference(self, keys: tuple) -> tuple[TestSplit, dict]:
        """The split and answers with the knobs `keys` at each sample's natural value."""
        if keys not in self.refs:
            t0 = time.perf_counter()
            fixed = {kk: PAIR_FIXED[kk] for kk in keys if kk in PAIR_FIXED}
            drawn = [kk for kk in keys if kk in PER_SAMPLE]
            per = ([{kk: self.natural[kk][j] for kk in drawn} for j in range(len(self.indices))]
                   if drawn else None)
            sp = self.renderer.split(self.pipeline.encoders, self.indices, knobs=fixed,
                                     per_sample=per)
            self.refs[keys] = (sp, answers(self.pipeline, sp, self.ctx.k, False))
            self.say(f"reference {'natural' if not keys else 'paired ' + '+'.join(keys)}: "
                     f"{time.perf_counter() - t0:.1f} s")
        return self.refs[keys]

    def knob(self, knob: str, settings: list[dict], drop: float) -> dict:
        """Every setting of one knob against its paired reference, with its break points."""
        keys = tuple(sorted({kk for s in settings for kk in s if kk in PER_SAMPLE}
                            | {kk for s in settings for kk in s if kk in PAIR_FIXED and s[kk]}))
        ref_split, ref_ans = self.reference(keys)
        mean = (float(np.mean(self.natural[knob])) if knob in PER_SAMPLE else None)
        points = [{"label": _label(knob, None, mean), "value": None, "x": _x(knob, None, mean),
                   "reference": True,
                   **score_point(ref_split, ref_ans, ref_split, ref_ans, self.ctx)}]
        for setting in settings:
            t0 = time.perf_counter()
            fallback = setting.get("missing") == "tactile"
            sp = self.renderer.split(self.pipeline.encoders, self.indices, knobs=setting)
            ans = answers(self.pipeline, sp, self.ctx.k, fallback)
            points.append({"label": _label(knob, setting, mean), "value": setting,
                           "x": _x(knob, setting, mean), "reference": False,
                           **score_point(sp, ans, ref_split, ref_ans, self.ctx),
                           "seconds": round(time.perf_counter() - t0, 1)})
            self.say(f"{knob}={points[-1]['label']}: {points[-1]['seconds']:.1f} s")
        return {"paired_reference": list(keys), "points": points,
                "break_points": break_points(points, self.ctx.k, drop)}
