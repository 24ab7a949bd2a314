"""Calibrating the trust signals on the world alone (`ratouch train trust`).

Reference: the embeddings of training-split renders (indices the encoders were trained on).
Validation: training-split renders from indices far beyond those the encoders saw, the same
distribution but unseen; every threshold is set there for the requested false-alarm rate.
The test split is only measured (false alarms of each signal on its 402 pairs, and the
no-contact detection rate on the same pairs rendered without contact), never used to set a
threshold.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass
from typing import Any

import numpy as np

from ratouch.errors import ConfigError
from ratouch.model.trust import (
    ContactModel,
    Novelty,
    TrustCalibration,
    background_change,
    contact_features,
    contact_features_free,
    threshold_for,
)
from ratouch.timing import progress_bar
from ratouch.world.config import WorldConfig
from ratouch.world.presses import render_blank_pair, render_press
from ratouch.world.sampler import TEST_SIZE, World
from ratouch.world.sensors import (
    WITHHOLD_LIMIT,
    guess_family,
    unfamiliar_look,
    unfamiliar_view,
    unfamiliar_views,
)
from ratouch.world.tactile import family_names, sensor_family

log = logging.getLogger(__name__)

#: First training-split index of the validation renders: beyond any training run's pairs.
VALIDATION_START = 1_000_000
#: Without a background, the share of validation presses (and of empty frames) allowed on
#: the wrong side of the "uncertain" band's edges.
UNCERTAIN_SHARE = 0.01
#: Drifted blank renders per family that `alone_band` sets its quantile on. A tail quantile
#: needs many: a GelSight's blanks score with a heavy tail (its units differ), and on 140 of
#: them the 99 % quantile moved between -1.20 and -0.72 from one random stream to the next
#: (on 600: -0.91 to -0.62).
ALONE_BLANKS = 600
#: Everyday presses (and as many drifted blanks) per family that `with_alone_band` fits a
#: family's press model on, and presses of a third stream it compares the two bands on.
ALONE_PRESSES = 300
ALONE_CHECK = 200
#: The world's renders with and without contact (each plain and under one unfamiliar view)
#: that `with_unfamiliar_contact` fits the colour-blind contact model on, and validation
#: presses (their views) it sets the threshold on.
UNFAMILIAR_FIT = 500
UNFAMILIAR_VALIDATION = 500


@dataclass(frozen=True)
class TrustConfig:
    """What `calibrate` renders and the false-alarm rate it targets.

    Attributes:
        seed: the world's seed.
        n_reference: training renders the novelty distances are fitted on.
        n_validation: unseen renders the thresholds are set on.
        false_alarm: share of in-distribution validation inputs each signal may flag.
        rank: principal directions kept by the novelty distances.
        n_everyday: per sensor family, renders of the presses people make
            (`ratouch.world.presses`: flat faces, fabrics, foams, tape, wire, edges, small
            curved objects) and as many drifted blank pairs, added to the with-background
            contact model's reference renders and again, freshly drawn, to its validation
            renders (`EVERYDAY_COLUMNS`).
        n_alone_blanks: per sensor family, drifted blank renders the no-background
            "uncertain" band is set on (`with_alone_band`; 0: no band).
        n_alone_presses, n_alone_check: per sensor family, everyday presses the band's
            press model is fitted on (0: the band stays on the contact logit) and presses
            the two bands are compared on (`with_alone_band`).
        n_unfamiliar: the world's reference renders with and without contact the
            colour-blind contact model for frames beyond every rendered unit is fitted on
            (`with_unfamiliar_contact`; 0, the default: none. Measured and not shipped:
            docs/geometry.md, "A sensor unlike every rendered unit, read alone").
        n_test: the test split's first pairs the calibration's rates are measured on
            (`meta.measured`; nothing is fitted or thresholded on them), the whole split by
            default.
    """

    seed: int = 0
    n_reference: int = 2000
    n_validation: int = 1000
    false_alarm: float = 0.02
    rank: int = 16
    n_everyday: int = 140
    n_alone_blanks: int = ALONE_BLANKS
    n_alone_presses: int = ALONE_PRESSES
    n_alone_check: int = ALONE_CHECK
    n_unfamiliar: int = 0
    n_test: int = TEST_SIZE

    def __post_init__(self) -> None:
        for name in ("n_reference", "n_validation"):
            if getattr(self, name) < 50:
                raise ConfigError(f"{name}={getattr(self, name)} must be >= 50")
        if not 0 < self.false_alarm < 0.5:
            raise ConfigError(f"false_alarm={self.false_alarm} must lie in (0, 0.5)")
        if not 1 <= self.rank < self.n_reference:
            raise ConfigError(f"rank={self.rank} must lie in [1, n_reference)")
        for name in ("n_everyday", "n_alone_blanks", "n_alone_presses", "n_alone_check",
                     "n_unfamiliar"):
            if getattr(self, name) < 0:
                raise ConfigError(f"{name}={getattr(self, name)} must be >= 0")
        if not 1 <= self.n_test <= TEST_SIZE:
            raise ConfigError(f"n_test={self.n_test} must lie in [1, {TEST_SIZE}] (the test "
                              "split's size)")


def render_samples(world: World, split: str, indices, progress: bool = False,
                   what: str = "samples") -> dict:
    """Crops, tactile frames, their sensors' backgrounds and families, and the materials of
    some samples."""
    out: dict[str, list] = {"crops": [], "frames": [], "backgrounds": [], "families": [],
                            "materials": []}
    for i in progress_bar(indices, desc=f"render {what}", progress=progress):
        s = world.sample(split, int(i))
        out["crops"].append(s.crop)
        out["frames"].append(s.tactile)
        out["backgrounds"].append(world.background_image(s.sensor))
        out["families"].append(sensor_family(s.sensor))
        out["materials"].append(s.material)
    return out


def _features(data: dict) -> tuple[np.ndarray, np.ndarray]:
    """Contact features of rendered frames without and with their backgrounds."""
    plain = np.stack([contact_features(f) for f in data["frames"]])
    with_bg = np.stack([contact_features(f, b) for f, b in zip(data["frames"], data["backgrounds"])])
    return plain, with_bg


def everyday_features(n: int, seed: int, progress: bool = False
                      ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Contact features (without, with the background) of `n` everyday presses per sensor
    family (`render_press`: kind and material drawn, the background captured at another
    moment, drifted as Taxim's real pairs drift) and of `n` drifted blank pairs per family:
    {"press": (plain, with_bg), "blank": (plain, with_bg)}."""
    rng = np.random.default_rng([seed, 3301])
    out: dict[str, tuple[list, list]] = {"press": ([], []), "blank": ([], [])}
    for fam in progress_bar(family_names(), desc="render everyday presses", progress=progress):
        for _ in range(n):
            p = render_press(fam, rng)
            out["press"][0].append(contact_features(p.frame))
            out["press"][1].append(contact_features(p.frame, p.background))
            frame, bg = render_blank_pair(fam, rng)
            out["blank"][0].append(contact_features(frame))
            out["blank"][1].append(contact_features(frame, bg))
    return {k: (np.asarray(a, np.float64).reshape(len(a), -1),
                np.asarray(b, np.float64).reshape(len(b), -1)) for k, (a, b) in out.items()}


#: The feature columns (0: without, 1: with the background) that the everyday renders join.
#: Without a background they overlap blank frames: with them in both columns (2026-11-28),
#: the no-background model recognised 85 % of the validation blanks (its threshold keeps 98 %
#: of the presses) and called 6.2 % of the test split's blanks contact, against the 5 % the
#: shipped calibration is held to; without them it recognises them all. A frame alone keeps
#: the disc-press model; the background is what reads a shallow press.
EVERYDAY_COLUMNS = (1,)


def _with_everyday(feats: dict, extra: dict, positives: str, negatives: str) -> None:
    """Append everyday presses to the `positives` features and blank pairs to the `negatives`
    (the `EVERYDAY_COLUMNS`), in place."""
    for split, kind in ((positives, "press"), (negatives, "blank")):
        feats[split] = tuple(np.concatenate([a, b]) if col in EVERYDAY_COLUMNS else a
                             for col, (a, b) in enumerate(zip(feats[split], extra[kind])))


def calibrate(encoders, cfg: TrustConfig = TrustConfig(), progress: bool = True
              ) -> TrustCalibration:
    """Fit and threshold the trust signals for `encoders`, and measure them on the test split.

    The contact models are fitted on reference renders with and without contact (the same
    samples rendered both ways, every sensor family), their thresholds set on validation
    presses for `false_alarm` (the share of real presses called "no contact"), and the rates
    of both errors measured per sensor family on the test split.

    Returns:
        The calibration; its `meta` holds the data used and the measured rates.
    """
    world = World(WorldConfig(seed=cfg.seed)).warm()
    nc_world = World(WorldConfig(seed=cfg.seed).with_stress(no_contact=1.0)).warm()
    ref = render_samples(world, "train", range(cfg.n_reference), progress, "reference")
    nc_ref = render_samples(nc_world, "train", range(cfg.n_reference), progress,
                            "reference, no contact")
    val_idx = range(VALIDATION_START, VALIDATION_START + cfg.n_validation)
    val = render_samples(world, "train", val_idx, progress, "validation")
    nc_val = render_samples(nc_world, "train", val_idx, progress, "validation, no contact")
    test = render_samples(world, "test", range(cfg.n_test), progress, "test")
    nc_test = render_samples(nc_world, "test", range(cfg.n_test), progress, "test, no contact")
    # per split: (image embeddings, tactile embeddings, the prior's features or None)
    enc: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray | None]] = {}
    for name, d in (("ref", ref), ("val", val), ("test", test)):
        V, P = encoders.encode_image_features(d["crops"]) if hasattr(
            encoders, "encode_image_features") else (encoders.encode_image(d["crops"]), None)
        enc[name] = (V, encoders.encode_tactile(d["frames"], d["backgrounds"]), P)
    # the tactile novelty also knows frames without a background
    ref_plain_t = encoders.encode_tactile(ref["frames"])
    fa = cfg.false_alarm
    novelty: dict[str, Novelty | None] = {}
    ref_t = np.concatenate([enc["ref"][1], ref_plain_t])
    for m, ref_x, val_x in (("visual", enc["ref"][0], enc["val"][0]),
                            ("tactile", ref_t, enc["val"][1]),
                            ("visual_prior", enc["ref"][2], enc["val"][2])):
        if ref_x is None:
            novelty[m] = None
            continue
        assert val_x is not None  # the same encoders give every split the same features
        model = Novelty.fit(ref_x, cfg.rank)
        novelty[m] = model.with_threshold(threshold_for(model.score(val_x), fa))
    visual, tactile, prior = novelty["visual"], novelty["tactile"], novelty["visual_prior"]
    assert visual is not None and tactile is not None  # image and tactile embeddings always exist
    feats = {name: _features(d) for name, d in (("ref", ref), ("nc_ref", nc_ref), ("val", val),
                                               ("nc_val", nc_val), ("test", test),
                                               ("nc_test", nc_test))}
    # the presses people make (shallow, broad, textured) and blanks against a drifted
    # background: fitted on one draw, thresholds set with a second, fresh one
    if cfg.n_everyday:
        _with_everyday(feats, everyday_features(cfg.n_everyday, cfg.seed, progress),
                       "ref", "nc_ref")
        _with_everyday(feats, everyday_features(cfg.n_everyday, cfg.seed + 1, progress),
                       "val", "nc_val")
    models: list[ContactModel] = []
    thresholds: list[float] = []
    for col in (0, 1):  # without, with the background
        contact = ContactModel.fit(feats["ref"][col], feats["nc_ref"][col])
        models.append(contact)
        thresholds.append(threshold_for(contact.score(feats["val"][col]), fa, above=False))
    # the noise floor: what no-contact validation renders differ from their background by
    changes = {name: np.array([background_change(f, b) for f, b in
                               zip(d["frames"], d["backgrounds"])])
               for name, d in (("val", val), ("nc_val", nc_val), ("test", test),
                               ("nc_test", nc_test))}
    noise_floor = float(np.quantile(changes["nc_val"], 0.995))
    # without a background: the band where presses and empty frames overlap on validation
    low = float(np.quantile(models[0].score(feats["val"][0]), UNCERTAIN_SHARE))
    high = float(np.quantile(models[0].score(feats["nc_val"][0]), 1 - UNCERTAIN_SHARE))
    band = (low, high) if low < high else None
    measured: dict[str, Any] = {
        "visual_false_alarm_test": _rate(visual.score(enc["test"][0]) > visual.threshold),
        "tactile_false_alarm_test": _rate(tactile.score(enc["test"][1]) > tactile.threshold),
    }
    if prior is not None:
        test_prior = enc["test"][2]
        assert test_prior is not None  # the same encoders give every split the same features
        measured["visual_prior_false_alarm_test"] = _rate(
            prior.score(test_prior) > prior.threshold)
    measured["noise_floor"] = round(noise_floor, 5)
    measured["presses_below_noise_floor_test"] = _rate(changes["test"] < noise_floor)
    measured["empty_below_noise_floor_test"] = _rate(changes["nc_test"] < noise_floor)
    measured["uncertain_band"] = None if band is None else [round(low, 4), round(high, 4)]
    if band is not None:
        measured["uncertain_test"] = _rate(np.r_[
            (models[0].score(feats["test"][0]) >= low) & (models[0].score(feats["test"][0]) < high),
            (models[0].score(feats["nc_test"][0]) >= low)
            & (models[0].score(feats["nc_test"][0]) < high)])
    families = np.asarray(test["families"])
    for col, suffix in ((0, ""), (1, "_bg")):
        press = models[col].score(feats["test"][col]) < thresholds[col]  # a press called empty
        empty = models[col].score(feats["nc_test"][col]) >= thresholds[col]  # empty called a press
        measured[f"contact_miss_test{suffix}"] = _rate(press)
        measured[f"contact_false_alarm_test{suffix}"] = _rate(empty)
        measured[f"validation_no_contact_detected{suffix}"] = _rate(
            models[col].score(feats["nc_val"][col]) < thresholds[col])
        for fam in family_names():
            sel = families == fam
            measured[f"contact_miss_test{suffix}_{fam}"] = _rate(press[sel])
            measured[f"contact_false_alarm_test{suffix}_{fam}"] = _rate(empty[sel])
    meta = {"world_seed": cfg.seed, "reference": f"train[0:{cfg.n_reference}] with and without contact",
            "validation": f"train[{VALIDATION_START}:{VALIDATION_START + cfg.n_validation}]",
            "test": f"test[0:{cfg.n_test}] (measured only)", "target_false_alarm": fa,
            "rank": cfg.rank, "families": list(family_names()),
            "everyday": (f"{cfg.n_everyday} presses and {cfg.n_everyday} drifted blank pairs "
                         "per family, in the with-background contact model's reference and, "
                         "fresh, validation"),
            "measured": measured}
    log.info("trust calibration for %s: %s", encoders.name, measured)
    cal = TrustCalibration(encoders.name, visual, tactile, models[0], models[1], thresholds[0],
                           thresholds[1], prior, meta, noise_floor, band)
    if cfg.n_alone_blanks:
        cal = with_alone_band(cal, cfg.n_alone_blanks, cfg.seed, nc_val, cfg.n_alone_presses,
                              cfg.n_alone_check, val)
    if cfg.n_unfamiliar:
        n = min(cfg.n_unfamiliar, cfg.n_reference)
        cal = with_unfamiliar_contact(
            cal, n, cfg.seed, fa,
            {"frames": ref["frames"][:n]}, {"frames": nc_ref["frames"][:n]}, val, nc_val)
    return cal


def with_unfamiliar_contact(trust: TrustCalibration, n: int = UNFAMILIAR_FIT, seed: int = 0,
                            false_alarm: float = TrustConfig.false_alarm,
                            presses: dict | None = None, blanks: dict | None = None,
                            val_presses: dict | None = None, val_blanks: dict | None = None,
                            n_validation: int = UNFAMILIAR_VALIDATION) -> TrustCalibration:
    """`trust` with its colour-blind contact model for frames alone that lie beyond every
    rendered unit (`contact_unfamiliar`, read where `guess_family` is beyond
    `WITHHOLD_LIMIT`).

    Fitted (`ContactModel` on `contact_features_free`) on `n` of the world's reference
    renders with contact (`presses`; None: train[0:n] rendered here) against `n` without
    (`blanks`), each plain and under one `unfamiliar_view`; thresholded so that `false_alarm`
    of the validation presses' views (`val_presses`; None: `validation_presses(seed)`, its
    first `n_validation`) that lie beyond the limit are missed. The share of the validation
    blanks' views beyond the limit called contact is recorded in `meta["unfamiliar_contact"]`.
    Every number is from renders.
    """
    if presses is None or blanks is None:
        world = World(WorldConfig(seed=seed)).warm()
        nc_world = World(WorldConfig(seed=seed).with_stress(no_contact=1.0)).warm()
        presses = render_samples(world, "train", range(n))
        blanks = render_samples(nc_world, "train", range(n))
    val_presses = validation_presses(seed) if val_presses is None else val_presses
    val_blanks = validation_blanks(seed) if val_blanks is None else val_blanks
    fit_rng = np.random.default_rng([seed, 3313])
    val_rng = np.random.default_rng([seed, 3317])

    def both(frames: list) -> np.ndarray:  # each frame plain and under one view
        return np.stack([contact_features_free(f) for f in frames]
                        + [contact_features_free(unfamiliar_view(f, fit_rng)) for f in frames])

    model = ContactModel.fit(both(presses["frames"][:n]), both(blanks["frames"][:n]))

    def beyond(frames: list) -> np.ndarray:  # features of the views beyond the limit
        views, _ = unfamiliar_views(frames[:n_validation], val_rng)
        return np.stack([contact_features_free(v) for v in views])

    vp, vb = beyond(val_presses["frames"]), beyond(val_blanks["frames"])
    threshold = threshold_for(model.score(vp), false_alarm, above=False)
    meta = {**trust.meta, "unfamiliar_contact": {
        "fit": f"the world's train[0:{n}] with and without contact, each plain and under one "
               "unfamiliar view (channels reordered, per-channel gain and offset, gamma)",
        "validation": f"views of the first {n_validation} validation renders with and without "
                      f"contact, those beyond WITHHOLD_LIMIT ({WITHHOLD_LIMIT}): "
                      f"{len(vp)} presses, {len(vb)} blanks",
        "target_miss": false_alarm, "threshold": round(threshold, 4),
        "validation_blanks_called_contact": _rate(model.score(vb) >= threshold)}}
    return dataclasses.replace(trust, contact_unfamiliar=(model, round(threshold, 4)), meta=meta)


def alone_band(trust: TrustCalibration, n: int = ALONE_BLANKS, seed: int = 0,
               world_blanks: dict | None = None) -> dict[str, float]:
    """`TrustCalibration.uncertain_alone` on the contact model's logit: per sensor family,
    the (1 - `UNCERTAIN_SHARE`) quantile of what the family's blank frames score alone with
    the no-background contact model: `n` drifted blank renders (`render_blank_pair`, a
    stream of their own) and the world's own no-contact renders of that family
    (`world_blanks`: {"frames", "families"}, as `render_samples` gives them; None:
    `validation_blanks(seed)`). A family whose blanks reach the contact threshold gets no
    band."""
    world_blanks = validation_blanks(seed) if world_blanks is None else world_blanks
    return _logit_bands(trust, _alone_blanks(n, seed, world_blanks))


def _logit_bands(trust: TrustCalibration, blanks: dict[str, list[np.ndarray]]
                 ) -> dict[str, float]:
    """`alone_band` on blank frames already rendered, per family."""
    out = {}
    for fam, frames in blanks.items():
        low = _edge([trust.contact_score(f) for f in frames])
        if low is not None and low < trust.contact_threshold:
            out[fam] = round(low, 4)
    return out


def _alone_blanks(n: int, seed: int, world_blanks: dict, part: slice = slice(None),
                  drifted: dict[str, list[np.ndarray]] | None = None
                  ) -> dict[str, list[np.ndarray]]:
    """Per family: `n` drifted blank renders of `alone_band`'s stream (`drifted`: those
    already rendered by `_drifted_blanks(n, seed)`) and the world's own no-contact renders
    of that family (`part` of them)."""
    drifted = _drifted_blanks(n, seed) if drifted is None else drifted
    return {fam: frames + _of_family(world_blanks, fam)[part] for fam, frames in drifted.items()}


def _drifted_blanks(n: int, seed: int) -> dict[str, list[np.ndarray]]:
    """Per family, `n` drifted blank renders of `alone_band`'s random stream."""
    rng = np.random.default_rng([seed, 3307])
    return {fam: [render_blank_pair(fam, rng)[0] for _ in range(n)] for fam in family_names()}


def _of_family(renders: dict, fam: str) -> list[np.ndarray]:
    """The frames of `renders` ({"frames", "families"}, as `render_samples` gives them) of
    sensor family `fam`."""
    return [f for f, name in zip(renders["frames"], renders["families"]) if name == fam]


def _edge(scores) -> float | None:
    """The band's edge over blank frames' scores: their (1 - `UNCERTAIN_SHARE`) quantile."""
    return float(np.quantile(scores, 1 - UNCERTAIN_SHARE)) if len(scores) else None


#: The families whose band gets the second reading (a press model read alone). The
#: GelSight's, sharing its family's 1 %, was refuted twice (2026-11-28: Taxim's real GelSight
#: background alone turned "uncertain"; 2026-12-01: one of the world's 402 test presses alone
#: turned "no contact"); with a share of its own (`OWN_SHARE_FAMILIES`, 2026-12-01, second
#: session, docs/geometry.md) every criterion fixed before the run held: refusals without a
#: background 0.614 -> 0.271 on fresh renders. The Mini's band answers every validation press
#: without it.
PRESS_MODEL_FAMILIES = ("digit", "gelsight")
#: Of `PRESS_MODEL_FAMILIES`, those whose press model gets a share of held-out blanks of its
#: own (`UNCERTAIN_SHARE` more of them may be "uncertain") while their logit edge stays where
#: `alone_band` puts it: the GelSight's logit edge spends its 1 % by itself, and raising it to
#: make room lost a world press (docs/geometry.md, 2026-12-01).
OWN_SHARE_FAMILIES = ("gelsight",)
#: Quantiles of the held-out blanks' contact logits tried as the band's logit edge when a
#: second reading shares the band (`with_alone_band`): lower leaves the press model more.
LOGIT_EDGE_LEVELS = (0.99, 0.992, 0.994, 0.996, 0.998, 1.0)


def with_alone_band(trust: TrustCalibration, n: int = ALONE_BLANKS, seed: int = 0,
                    world_blanks: dict | None = None, n_presses: int = ALONE_PRESSES,
                    n_check: int = ALONE_CHECK, world_presses: dict | None = None,
                    families: tuple[str, ...] = PRESS_MODEL_FAMILIES) -> TrustCalibration:
    """`trust` with its no-background "uncertain" band (`uncertain_alone`, `press_alone`),
    which calls at most `UNCERTAIN_SHARE` of a family's held-out blank frames "uncertain"
    (`n` drifted blank renders and the odd-numbered half of the world's own no-contact
    renders of the family, `world_blanks`; None: `validation_blanks(seed)`).

    A family not in `families` gets `alone_band`'s band (on every world blank). Per sensor
    family of `families`, a frame alone is "uncertain" above either of two edges:

    * on the disc-press contact model's logit (`alone_band`'s reading);
    * on a press model read alone: a `ContactModel` of `n_presses` everyday presses
      (`render_press`, kind and material drawn) and the even-numbered half of the world's
      own presses of the family (`world_presses`; None: `validation_presses(seed)`) against
      `n_presses` drifted blanks and the even-numbered half of the world's blanks, all of
      streams of their own.

    For a family of `OWN_SHARE_FAMILIES` the logit's edge stays where `alone_band` puts it
    and the press model's is set as low as `UNCERTAIN_SHARE` more of the held-out blanks
    allows (those the logit edge leaves "no contact"): up to twice the share is "uncertain".
    For the others the logit's edge is tried at each quantile of `LOGIT_EDGE_LEVELS` of the held-out
    blanks, the press model's then set as low as the share of blanks allows; the pair that
    answers most presses of a third stream (`n_check` everyday presses and the odd-numbered
    half of the world's presses: contact or "uncertain", as `contact_state` decides), and
    no fewer of those world presses than the logit alone, is kept, the logit alone (at the 99 % quantile, as `alone_band`) where the press model adds
    nothing. `meta["alone_band"]` records the comparison. Every number is from renders.
    """
    world_blanks = validation_blanks(seed) if world_blanks is None else world_blanks
    world_presses = validation_presses(seed) if world_presses is None else world_presses
    drifted = _drifted_blanks(n, seed)  # rendered once: both bands read them
    held = {fam: frames for fam, frames in _alone_blanks(
        n, seed, world_blanks, slice(1, None, 2), drifted).items() if fam in families}
    fit_world = {"frames": world_blanks["frames"][0::2],
                 "families": world_blanks["families"][0::2]}
    fitting = _alone_blanks(n_presses, seed + 1, fit_world) if n_presses and held else {}
    fit_rng = np.random.default_rng([seed, 3309])
    check_rng = np.random.default_rng([seed, 3311])
    logit_bands = _logit_bands(trust, _alone_blanks(n, seed, world_blanks, drifted=drifted))
    bands = {fam: edge for fam, edge in logit_bands.items()
             if fam not in families or fam in OWN_SHARE_FAMILIES}
    second: dict[str, tuple[ContactModel, float]] = {}
    record: dict[str, dict] = {}
    base = dataclasses.replace(trust, uncertain_alone=None, press_alone=None)
    for fam, blanks in held.items():
        if not blanks:
            continue
        # each frame's contact features once: the contact model's logit and the press
        # model's read the same ones (`contact_score` is the contact model on them)
        blank_feats = np.stack([contact_features(f) for f in blanks])
        logits = trust.contact.score(blank_feats)
        own_share = fam in OWN_SHARE_FAMILIES
        edge = _edge(logits)
        if not own_share and edge is not None and edge < trust.contact_threshold:
            bands[fam] = round(edge, 4)
        if not n_presses:
            continue
        own = _of_family(world_presses, fam)
        model = ContactModel.fit(
            np.stack([contact_features(render_press(fam, fit_rng).frame)
                      for _ in range(n_presses)] + [contact_features(f) for f in own[0::2]]),
            np.stack([contact_features(f) for f in fitting[fam]]))
        pressed = model.score(blank_feats)
        checks = [render_press(fam, check_rng).frame for _ in range(n_check)] + own[1::2]
        # what the calibration answers without any band, and what the band would read
        answered0 = np.array([base.contact_state(f)[0] != "no contact" for f in checks])
        guesses = [guess_family(f) for f in checks]
        looks = np.array([g[0] == fam and not unfamiliar_look(g) for g in guesses])
        check_feats = np.stack([contact_features(f) for f in checks])
        c_logit = trust.contact.score(check_feats)
        c_press = model.score(check_feats)
        allowed = int(np.floor(UNCERTAIN_SHARE * len(blanks)))
        options = []
        # a share of its own: the logit edge as `alone_band` sets it, and `allowed` more
        # held-out blanks for the press model; else the two share `allowed`
        levels = (LOGIT_EDGE_LEVELS[0],) if own_share else LOGIT_EDGE_LEVELS
        for level in levels:
            e1 = float(np.quantile(logits, level)) if level < 1 else float("inf")
            if level == LOGIT_EDGE_LEVELS[0] and fam in bands:
                e1 = bands[fam]
            left = pressed[logits < e1]
            room = allowed - (0 if own_share else int((logits >= e1).sum()))
            if room < 0 or not len(left):
                continue
            e2 = float(np.sort(left)[::-1][room]) + 1e-6 if room < len(left) else -np.inf
            hit = answered0 | (looks & ((c_logit >= e1) | (c_press >= e2)))
            options.append((float(hit.mean()), level, e1, e2, int(hit[n_check:].sum())))
        only = answered0 | (looks & (c_logit >= bands.get(fam, np.inf)))
        logit_only = float(only.mean())
        # the world's own presses: none that the logit band answers may be lost
        options = [o for o in options if o[4] >= int(only[n_check:].sum())]
        best = max(options, key=lambda o: (o[0], -o[1])) if options else None
        keep = best is not None and best[0] > logit_only and np.isfinite(best[3])
        if keep:
            assert best is not None
            _, level, e1, e2, _ = best
            if np.isfinite(e1) and e1 < trust.contact_threshold:
                bands[fam] = round(e1, 4)
            else:
                bands.pop(fam, None)
            second[fam] = (model, round(e2, 4))
        record[fam] = {
            "answered_on_check_presses": {"logit": round(logit_only, 4),
                                          "logit_and_press_model": None if best is None
                                          else round(best[0], 4)},
            "logit_edge": bands.get(fam), "logit_edge_level": best[1] if keep and best else 0.99,
            "press_model_edge": second[fam][1] if fam in second else None,
            "blank_share_allowed": 2 * UNCERTAIN_SHARE if own_share else UNCERTAIN_SHARE,
            "uses": ("logit and press model" + (" (a share of its own)" if own_share else "")
                     if keep else "logit")}
    meta = {**trust.meta, "alone_band": {
        "blanks": f"{n} drifted blank renders and the odd half of the world's no-contact "
                  "validation renders per family (at most "
                  f"{UNCERTAIN_SHARE:.0%} of them uncertain)",
        "press_model": f"{n_presses} everyday presses and the even half of the world's "
                       f"validation presses against {n_presses} drifted blanks and the even "
                       "half of the world's blanks per family",
        "check": f"{n_check} everyday presses per family (a third stream) and the odd half "
                 "of the world's validation presses",
        "second_reading_tried_on": list(families), "families": record}}
    return dataclasses.replace(trust, uncertain_alone=bands or None,
                               press_alone=second or None, meta=meta)


def validation_presses(seed: int = 0, n: int = TrustConfig.n_validation) -> dict:
    """The world's validation renders with contact (`calibrate`'s "val")."""
    world = World(WorldConfig(seed=seed)).warm()
    return render_samples(world, "train", range(VALIDATION_START, VALIDATION_START + n))


def validation_blanks(seed: int = 0, n: int = TrustConfig.n_validation) -> dict:
    """The world's no-contact validation renders (`calibrate`'s "nc_val"): what a blank
    sensor looks like in the world the models were trained on."""
    nc_world = World(WorldConfig(seed=seed).with_stress(no_contact=1.0)).warm()
    return render_samples(nc_world, "train", range(VALIDATION_START, VALIDATION_START + n))


def _rate(flags: np.ndarray) -> float:
    return round(float(np.mean(flags)), 4) if len(flags) else float("nan")
