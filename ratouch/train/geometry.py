"""Fitting the geometry lookups (`ratouch train geometry`): per sensor family, a colour-change
-to-gradient lookup and the noise floors of its height maps (`ratouch.model.geometry`).

* **GelSight, GelSight Mini**: fitted on Taxim's real ball presses (`calib/*/dataPack.npz`:
  frames, the no-contact frame, each touch's annotated centre and radius), every sixth press
  held out of the fit to measure the reconstruction (depth and contact radius against the
  sphere's). The ball's radius is not stored with the calibrations; Taxim's calibration
  procedure presses "a small sphere (about 4 mm)", so :data:`BALL_MM` = 2.0. Pixel size:
  the calibration's `pixmm`.
* **DIGIT**: no real calibration exists; the lookup is fitted on the world shader's own
  renders of ball presses (so a render is inverted exactly by the shader's mapping, and a
  real DIGIT frame gets the shader's mapping too: its depth is in render units, a guess).
* **Firmness from shape**: per family, a logistic model on :func:`shape_features` of
  renders of every kind of everyday press (`ratouch.world.presses.render_press`, a stream of
  its own) read against their drifted backgrounds; soft is compliance >= 0.5. Renders only.
* **Contact floors**: per family, the 99.5th percentiles of the structured change
  (`ratouch.model.geometry.band_stats`) over blank pairs (a unit's background and a
  later no-contact frame, drifted as Taxim's real pairs drift: `ratouch.world.presses`).
  Renders only: no real frame sets a threshold.
* **Floors for a sensor unlike every rendered unit** (`set_unfamiliar_floors`): per family's
  lookup, the same statistics over blank pairs of every family's units, each pair recoloured
  alike (`ratouch.world.sensors.unfamiliar_view`) to lie beyond every rendered unit, read
  through that lookup. Renders only.
"""

from __future__ import annotations

import dataclasses
import logging
from typing import Any

import numpy as np

from ratouch.errors import ConfigError
from ratouch.model.geometry import (
    FIELD_CHECK_FAMILIES,
    WORK_LANDSCAPE,
    FirmnessModel,
    GeometryCalibration,
    GradientLookup,
    RoutedFirmness,
    band_stats,
    fit_lookup,
    noise_adjusted,
    press_shape,
    read_height,
    sphere_gradients,
    structure_score,
    working_change,
)
from ratouch.world.presses import BALL_MM

log = logging.getLogger(__name__)

#: Every how-many-th real press is held out of a lookup's fit.
HOLD_OUT_EVERY = 6
#: Blank pairs per family the floors are set on, and the quantile.
FLOOR_PAIRS = 300
FLOOR_QUANTILE = 0.995
#: Renders per kind of press (`ratouch.world.presses.PRESS_KINDS`) each family's firmness
#: model is fitted on.
FIRMNESS_PER_KIND = 60
#: World training renders with contact per family the firmness model also reads (the world's
#: own frames: a material pressed firmly, its compliance in the patch's size and edge), and
#: where their stream starts in the train split (no other fit draws from it).
FIRMNESS_WORLD = 300
FIRMNESS_WORLD_START = 1_800_000
#: Columns of `shape_features` in each group, for the fit's report (the height map's profile
#: and the change's structured statistics).
PROFILE_COLUMNS = tuple(range(14))
CHANGE_COLUMNS = tuple(range(14, 20))


def _taxim_pixels(calibration: str) -> float:
    """Working pixels per full-resolution pixel of a Taxim calibration."""
    return WORK_LANDSCAPE[0] / 640.0


def fit_taxim(name: str, calibration: str, seed: int = 0, samples: int = 120_000
              ) -> tuple[GradientLookup, dict]:
    """A landscape family's lookup fitted on its calibration's real presses; and the held-out
    reconstruction (per held-out press: depth in mm against the sphere's, contact radius in
    full-resolution pixels against the annotated one)."""
    from ratouch.world.taxim_optics import optics, real_presses

    rp = real_presses(calibration)
    pixmm = optics(calibration).pixmm
    s = _taxim_pixels(calibration)
    mm_per_work = pixmm / s
    ball = BALL_MM / mm_per_work  # working pixels
    bg = rp["background"]
    n = len(rp["frames"])
    held = [i for i in range(n) if i % HOLD_OUT_EVERY == 0]
    changes, targets, masks = [], [], []
    for i in range(n):
        if i in held:
            continue
        change = working_change(rp["frames"][i], bg, WORK_LANDSCAPE)
        cx, cy = rp["centres"][i] * s
        r = float(rp["radii"][i]) * s
        g, _, _ = sphere_gradients(change.shape[:2], (cx, cy), r * 0.97, ball)
        yy, xx = np.mgrid[:change.shape[0], :change.shape[1]]
        d = np.hypot(xx - cx, yy - cy)
        masks.append((d < 0.95 * r) | (d > 1.5 * r))  # the rim left out: its annotation is loose
        changes.append(change)
        targets.append(g)
    lookup = fit_lookup(name, changes, targets, masks, landscape=True, mm_per_pixel=mm_per_work,
                        seed=seed, samples=samples, meta={"fitted_on": f"Taxim's {calibration} real ball presses "
                                         f"({n - len(held)} of {n}; every {HOLD_OUT_EVERY}th "
                                         "held out)", "ball_mm": BALL_MM,
                                         "pixmm": pixmm})
    rows = []
    for i in held:
        hm = read_height(lookup, rp["frames"][i], bg)
        r = float(rp["radii"][i])
        r_mm = r * pixmm
        true_depth = BALL_MM - float(np.sqrt(max(BALL_MM ** 2 - r_mm ** 2, 0.0)))
        radius = float(np.sqrt((hm.height > hm.depth / 3).sum() / np.pi)) / s
        rows.append({"press": i, "depth": round(hm.depth, 4),
                     "sphere_depth": round(true_depth, 4),
                     "radius_px": round(radius, 1), "annotated_radius_px": round(r, 1)})
    return lookup, _summary(rows, "mm")


def _summary(rows: list[dict], units: str) -> dict:
    dd = np.array([r["depth"] - r["sphere_depth"] for r in rows])
    rel = np.array([r["depth"] / r["sphere_depth"] - 1 for r in rows])
    dr = np.array([r["radius_px"] - r["annotated_radius_px"] for r in rows])
    return {"presses": rows, "units": units, "depth_error_mean": round(float(dd.mean()), 4),
            "depth_error_mae": round(float(np.abs(dd).mean()), 4),
            "depth_error_relative_mae": round(float(np.abs(rel).mean()), 4),
            "radius_error_px_mean": round(float(dr.mean()), 2),
            "radius_error_px_mae": round(float(np.abs(dr).mean()), 2)}


def fit_shader(name: str, seed: int = 0, presses: int = 40, samples: int = 120_000
               ) -> tuple[GradientLookup, dict]:
    """A shader family's lookup, fitted on the shader's renders of ball presses (in its own
    render units), and the reconstruction of held-out renders."""
    from ratouch.world.sensors import family_sensors
    from ratouch.world.tactile import (
        _SHADER_RELIEF,  # the shader's height scale
        contact_change,
        sensor_background,
    )

    rng = np.random.default_rng([seed, 31])
    w, h = WORK_LANDSCAPE[1], WORK_LANDSCAPE[0]  # portrait working size (width, height)
    units = list(family_sensors(name))
    frames = []
    for i in range(presses):
        sensor = units[i % len(units)]
        r = float(rng.uniform(0.12, 0.35)) * w
        ball = r / float(rng.uniform(0.5, 0.95))
        cx, cy = rng.uniform(0.3, 0.7) * w, rng.uniform(0.3, 0.7) * h
        g, cap, inside = sphere_gradients((h, w), (cx, cy), r, ball)
        field = sensor_background(sensor, (h, w)).astype(np.float64)
        change = contact_change(sensor, cap / _SHADER_RELIEF)
        frame = (np.clip(field + change + rng.normal(0, 0.004, field.shape), 0, 1) * 255 + .5
                 ).astype(np.uint8)
        frames.append((frame, (field * 255 + .5).astype(np.uint8), g, cap, r))
    held = set(range(0, presses, HOLD_OUT_EVERY))
    changes, targets, masks = [], [], []
    for i, (frame, bg, g, _, _r) in enumerate(frames):
        if i in held:
            continue
        changes.append(working_change(frame, bg, (w, h)))
        targets.append(g)
        masks.append(np.ones(g.shape[:2], bool))
    lookup = fit_lookup(name, changes, targets, masks, landscape=False, mm_per_pixel=None,
                        seed=seed, samples=samples, meta={"fitted_on": f"the world shader's renders of "
                                         f"{presses - len(held)} ball presses (render units)"})
    rows = []
    for i in sorted(held):
        frame, bg, _, cap, r = frames[i]
        hm = read_height(lookup, frame, bg)
        radius = float(np.sqrt((hm.height > hm.depth / 3).sum() / np.pi))
        rows.append({"press": i, "depth": round(hm.depth, 4),
                     "sphere_depth": round(float(cap.max()), 4),
                     "radius_px": round(radius, 1), "annotated_radius_px": round(r, 1)})
    return lookup, _summary(rows, "render units")


def floors_and_threshold(fit: np.ndarray, held: np.ndarray,
                         held_noise: np.ndarray | None = None
                         ) -> tuple[tuple[float, ...], float]:
    """Structured-change floors from blank pairs' `band_stats`: each statistic's
    :data:`FLOOR_QUANTILE` over `fit`, and the threshold, that quantile of the combined score
    (`structure_score`) over `held`, pairs the floors were not set on (each divided by how
    much noisier it is than the floors' blanks where `held_noise` gives that ratio, as the
    family's floors are read: `GradientLookup.contact`)."""
    floors = tuple(float(v) for v in np.quantile(fit, FLOOR_QUANTILE, axis=0))
    scores = [structure_score(s, floors) for s in held]
    if held_noise is not None:
        scores = [noise_adjusted(sc, float(r), 1.0) for sc, r in zip(scores, held_noise)]
    return floors, float(np.quantile(scores, FLOOR_QUANTILE))


def set_floors(lookup: GradientLookup, seed: int = 0, pairs: int = FLOOR_PAIRS
               ) -> GradientLookup:
    """The lookup with its structured-change floors set on drifted blank pairs of its
    family: each statistic's quantile, then the quantile of the combined score on a second,
    independent half of the pairs (so that the threshold is not set on the floors' own
    data)."""
    from ratouch.world.presses import render_blank_pair

    rng = np.random.default_rng([seed, 47])
    blanks = [render_blank_pair(lookup.family, rng) for _ in range(pairs)]
    floors, threshold, noise_ref = _floors_of([lookup.change_and_noise(*p) for p in blanks])
    on = (f"{pairs} drifted blank render pairs of the family: floors on {pairs // 2}, the "
          f"threshold on the other {pairs - pairs // 2}, {FLOOR_QUANTILE:.1%} quantiles; the "
          f"floors' noise their median on the first {pairs // 2}")
    out = lookup.with_floors(floors, threshold, noise_ref, floors_on=on)
    if lookup.family in FIELD_CHECK_FAMILIES:
        # the second reading's floors: the same pairs, a smooth lighting field removed
        floors, threshold, noise_ref = _floors_of(
            [lookup.change_and_noise(*p, field=True) for p in blanks])
        out = out.with_field_floors(floors, threshold, noise_ref,
                                    field_floors_on=on + ", read with a lighting field removed")
    return out


def _floors_of(read: list[tuple[np.ndarray, float]]) -> tuple[tuple[float, ...], float, float]:
    """Floors, threshold and noise reference from blank pairs' (change, noise): floors on
    the first half, the threshold on the second (`floors_and_threshold`); the noise the
    floors are set at (a pair noisier than this is read against its own) the first half's
    median."""
    stats = np.array([band_stats(change) for change, _ in read])
    noise = np.array([n for _, n in read])
    half = len(read) // 2
    noise_ref = float(np.median(noise[:half]))
    floors, threshold = floors_and_threshold(stats[:half], stats[half:],
                                             noise[half:] / noise_ref)
    return floors, threshold, noise_ref


def set_unfamiliar_floors(lookups: dict[str, GradientLookup], seed: int = 0,
                          pairs: int = FLOOR_PAIRS) -> dict[str, GradientLookup]:
    """Each lookup with its floors for a sensor unlike every rendered unit: `pairs` drifted
    blank pairs of every family's units, each frame and its background under one
    `unfamiliar_view` (the same for both), those that lie beyond every rendered unit
    (`beyond_every_unit`) kept and read through each lookup; each statistic's quantile on
    half of them (alternately), the combined score's quantile on the other half, as
    `set_floors` does for a family's own units.

    Raises:
        ConfigError: `pairs` < 2 (no half to set the threshold on).
    """
    from ratouch.world.presses import render_blank_pair
    from ratouch.world.sensors import beyond_every_unit, family_names, unfamiliar_pair_view

    if pairs < 2:
        raise ConfigError(f"pairs must be at least 2, got {pairs}")
    stats: dict[str, list[np.ndarray]] = {name: [] for name in lookups}
    kept = 0
    for k, source in enumerate(family_names()):
        rng = np.random.default_rng([seed, 48, k])
        for _ in range(pairs):
            frame, background = unfamiliar_pair_view(*render_blank_pair(source, rng), rng)
            if not beyond_every_unit(frame):
                continue
            kept += 1
            # the structured change depends on the lookup's working size and orientation
            # only: lookups that share them read one change
            read: dict[tuple, np.ndarray] = {}
            for name, lookup in lookups.items():
                key = (lookup.work_size, lookup.landscape)
                if key not in read:
                    read[key] = band_stats(lookup.change(frame, background))
                stats[name].append(read[key])
    out = {}
    for name, lookup in lookups.items():
        s = np.array(stats[name])
        floors, threshold = floors_and_threshold(s[0::2], s[1::2])
        out[name] = lookup.with_unfamiliar_floors(floors, threshold, unfamiliar_floors_on=(
            f"{kept} drifted blank render pairs of every family's units, each recoloured "
            f"beyond every rendered unit ({pairs} a family drawn): floors on every other one, "
            f"the threshold on the rest, {FLOOR_QUANTILE:.1%} quantiles"))
    return out


def with_unfamiliar_floors(cal: GeometryCalibration, seed: int = 0,
                           pairs: int = FLOOR_PAIRS) -> GeometryCalibration:
    """`cal` with every lookup's floors for a sensor unlike every rendered unit (re)set
    (`set_unfamiliar_floors`); the rest unchanged."""
    return dataclasses.replace(cal, lookups=set_unfamiliar_floors(cal.lookups, seed, pairs),
                               meta={**cal.meta, "unfamiliar_blank_pairs": pairs})


def shape_renders(lookup: GradientLookup, rng: np.random.Generator, per_kind: int
                  ) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """`per_kind` renders of every kind of everyday press on `lookup`'s family, read against
    their drifted backgrounds: their shape features (N, 20), whether each is soft (N,) bool,
    and each kind."""
    from ratouch.world.presses import render_presses

    presses = render_presses(lookup.family, rng, per_kind)
    return (np.asarray([press_shape(lookup, p.frame, p.background) for p in presses]),
            np.asarray([p.soft for p in presses], bool), [p.kind for p in presses])


def _logistic(X: np.ndarray, y: np.ndarray):  # noqa: ANN202 (an sklearn pipeline)
    from sklearn.linear_model import LogisticRegression
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler

    return make_pipeline(StandardScaler(), LogisticRegression(
        max_iter=2000, class_weight="balanced")).fit(X, y) if len(X) else None


def world_shape_renders(lookups: dict[str, GradientLookup], per_family: int,
                        start: int = FIRMNESS_WORLD_START, split: str = "train",
                        stop: int | None = None) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per family of `lookups`: the shape features (N, 20) of the world's renders with contact
    (`split` from `start`, before `stop` where given, the default world, the first
    `per_family` frames of each family) read against their unit's background, and whether
    each pressed material is soft (compliance >= 0.5). Only the tactile frame of each sample
    is rendered."""
    from ratouch.world.config import WorldConfig
    from ratouch.world.presses import SOFT_AT
    from ratouch.world.sampler import World
    from ratouch.world.sensors import sensor_family
    from ratouch.world.tactile import render_tactile

    world = World(WorldConfig())
    rows: dict[str, tuple[list, list]] = {name: ([], []) for name in lookups}
    need = {name: per_family for name in lookups}
    index = start
    stop = start + 50 * per_family * max(len(lookups), 1) if stop is None else stop
    while any(need.values()) and index < stop:
        _, _, mat, _, touch, _, _ = world.plan(split, index)
        index += 1
        name = sensor_family(touch.sensor)
        if not touch.contact or not need.get(name):
            continue
        frame = render_tactile(touch, world.pyramid, world.cfg.tactile_hw,
                               world.sensor_background(touch.sensor))
        rows[name][0].append(press_shape(lookups[name], frame,
                                         world.background_image(touch.sensor)))
        rows[name][1].append(mat.feel.compliance >= SOFT_AT)
        need[name] -= 1
    return {name: (np.asarray(X, np.float64).reshape(len(y), -1), np.asarray(y, bool))
            for name, (X, y) in rows.items()}


def _cv(X: np.ndarray, y: np.ndarray, groups: bool = True) -> dict:
    """5-fold balanced accuracy of the logistic model on both feature groups together and
    (`groups`) on each alone (None where a class has fewer than 2 renders)."""
    from sklearn.model_selection import cross_val_score

    folds = int(min(5, y.sum(), (~y).sum()))
    cv = {}
    for name, cols in (("both", None), ("profile", PROFILE_COLUMNS),
                       ("change", CHANGE_COLUMNS))[:3 if groups else 1]:
        Xg = X if cols is None else X[:, list(cols)]
        cv[name] = (round(float(cross_val_score(
            _logistic(Xg, y), Xg, y, cv=folds, scoring="balanced_accuracy").mean()), 3)
            if folds >= 2 else None)
    return cv


def _model(family: str, X: np.ndarray, y: np.ndarray, meta: dict) -> FirmnessModel:
    """The logistic model on standardised features, as a `FirmnessModel` (its probability:
    of the class `y` marks True)."""
    fit = _logistic(X, y)
    scaler, model = fit.named_steps["standardscaler"], fit.named_steps["logisticregression"]
    return FirmnessModel(family, np.asarray(scaler.mean_, np.float64),
                         np.asarray(scaler.scale_, np.float64),
                         np.asarray(model.coef_[0], np.float64), float(model.intercept_[0]),
                         meta)


def fit_firmness(lookup: GradientLookup, seed: int = 0, per_kind: int = FIRMNESS_PER_KIND,
                 world: tuple[np.ndarray, np.ndarray] | None = None
                 ) -> tuple[FirmnessModel | RoutedFirmness, dict]:
    """`lookup`'s family's firmness model, fitted on renders of everyday presses (a stream
    of its own); with `world`, the (features, soft) of the world's own renders
    (`world_shape_renders`), a `RoutedFirmness`: the everyday model, a model of the world's
    renders alone and a router between the two regimes. And the fit's report: renders, soft
    share, and 5-fold balanced accuracy of the everyday model on both feature groups together
    and on each alone (with `world`: of the world's model and of the router too)."""
    rng = np.random.default_rng([seed, 53, sum(map(ord, lookup.family))])
    X, y, _ = shape_renders(lookup, rng, per_kind)
    soft = "soft: compliance >= 0.5"
    report = {"renders": int(len(y)), "soft_share": round(float(y.mean()), 3),
              "cv_balanced_accuracy": _cv(X, y), "seed": seed, "per_kind": per_kind}
    everyday = _model(lookup.family, X, y, {
        "fitted_on": f"{len(y)} renders of everyday presses ({per_kind} a kind), {soft}",
        **report})
    if world is None or not len(world[1]):
        return everyday, report
    Xw, yw = world
    if min(yw.sum(), (~yw).sum()) < 2:
        raise ConfigError(f"the {len(yw)} world renders of {lookup.family} hold "
                          f"{int(yw.sum())} soft and {int((~yw).sum())} hard: too few of "
                          "one to fit its firmness model (give more with --firmness-world)")
    fed = f"train[{FIRMNESS_WORLD_START}:]"
    world_report = {"renders": int(len(yw)), "soft_share": round(float(yw.mean()), 3),
                    "cv_balanced_accuracy": _cv(Xw, yw, groups=False)}
    Xr = np.concatenate([X, Xw])
    yr = np.r_[np.zeros(len(y), bool), np.ones(len(yw), bool)]
    router_report = {"cv_balanced_accuracy": _cv(Xr, yr, groups=False)}
    routed = RoutedFirmness(
        lookup.family, everyday,
        _model(lookup.family, Xw, yw, {"fitted_on": f"{len(yw)} of the world's renders "
                                       f"with contact ({fed}), {soft}", **world_report}),
        _model(lookup.family, Xr, yr, {"fitted_on": f"the {len(y)} everyday presses (0) "
                                       f"and the {len(yw)} world renders (1)",
                                       **router_report}),
        {"fitted_on": f"{len(y)} renders of everyday presses ({per_kind} a kind) and "
                      f"{len(yw)} of the world's renders with contact ({fed}): a model "
                      f"each, mixed by a router; {soft}"})
    return routed, {**report, "world": world_report, "router": router_report}


def with_firmness(cal: GeometryCalibration, seed: int = 0,
                  per_kind: int = FIRMNESS_PER_KIND, world: int = FIRMNESS_WORLD
                  ) -> tuple[GeometryCalibration, dict]:
    """`cal` with every family's firmness model fitted (its lookups unchanged) on `per_kind`
    everyday presses a kind and `world` of the world's renders with contact a family, and the
    fits' reports."""
    pool = world_shape_renders(cal.lookups, world) if world else {}
    models, report = {}, {}
    for name, lookup in cal.lookups.items():
        models[name], report[name] = fit_firmness(lookup, seed, per_kind, pool.get(name))
        log.info("firmness %s: cv balanced accuracy %s (world %s, router %s)", name,
                 report[name]["cv_balanced_accuracy"], report[name].get("world"),
                 report[name].get("router"))
    return GeometryCalibration(cal.lookups, cal.meta, models), report


def with_family_floors(cal: GeometryCalibration, seed: int = 0, pairs: int = FLOOR_PAIRS
                       ) -> GeometryCalibration:
    """`cal` with every family's floors, threshold and their noise set again (`set_floors`:
    the draws `calibrate` makes), its lookups, floors for an unfamiliar sensor and firmness
    models unchanged."""
    lookups = {name: set_floors(lookup, seed, pairs) for name, lookup in cal.lookups.items()}
    return dataclasses.replace(cal, lookups=lookups)


def calibrate(seed: int = 0, samples: int = 120_000, pairs: int = FLOOR_PAIRS,
              per_kind: int = FIRMNESS_PER_KIND, world: int = FIRMNESS_WORLD
              ) -> tuple[GeometryCalibration, dict[str, Any]]:
    """Every family's lookup with its floors and its firmness model, and per family the
    held-out reconstruction and the firmness fit's report (`samples`: pixels each lookup is
    fitted on; `pairs`: blank pairs the floors are set on; `per_kind`: renders per kind of
    press the firmness model is fitted on; `world`: the world's renders a family it also
    reads)."""
    from ratouch.world.sensors import SENSOR_FAMILIES

    lookups, report = {}, {}
    for name, row in SENSOR_FAMILIES.items():
        if row.renderer == "taxim":
            lookup, rec = fit_taxim(name, str(row.calibration), seed, samples=samples)
        else:
            lookup, rec = fit_shader(name, seed, samples=samples)
        lookup = set_floors(lookup, seed, pairs=pairs)
        lookups[name] = lookup.with_floors(lookup.structure_floors,
                                           lookup.structure_threshold, held_out=_brief(rec))
        report[name] = rec
        log.info("geometry %s: depth MAE %s, radius MAE %s px, threshold %.3g", name,
                 rec["depth_error_mae"], rec["radius_error_px_mae"],
                 lookup.structure_threshold)
    lookups = set_unfamiliar_floors(lookups, seed, pairs)
    cal, firmness = with_firmness(GeometryCalibration(
        lookups, {"seed": seed, "ball_mm": BALL_MM, "samples": samples,
                  "blank_pairs": pairs, "unfamiliar_blank_pairs": pairs}),
        seed, per_kind, world)
    for name, rec in firmness.items():
        report[name]["firmness"] = rec
    return cal, report


def _brief(rec: dict) -> dict:
    return {k: v for k, v in rec.items() if k != "presses"}
