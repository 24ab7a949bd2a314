"""Trust signals for a query: how unlike the training data each input is, and whether the
tactile frame shows any contact at all.

* **Novelty** (per modality): a probabilistic-PCA Mahalanobis distance of the visual or
  tactile embedding from the embeddings of the world's training renders (the data the
  encoders were trained on): the top principal directions are whitened by their variances,
  the rest by the mean residual variance. Large means "unlike anything trained on": the
  retrieved neighbours and descriptions are then guesses.
  The visual distance is measured in the frozen visual prior's feature space (features of
  real photos: a photo stands far from every render there, while a render-trained head may
  map it anywhere); encoders without a prior use their own embedding.
* **No contact**: a tactile frame with nothing pressed into the gel is the sensor's
  background. A small logistic model (:class:`ContactModel`) reads multi-scale band-pass
  statistics of the frame, or of its difference from the background frame when that is
  known (log RMS and 99th percentile per band, and the finest band's noise level), and
  scores contact. It is trained across the world's sensor families (a crisp DIGIT-like one,
  a GelSight with marker dots, a low-contrast GelSight-Mini-like one) on renders only, with
  and without contact. Features are computed at a fixed working resolution
  (:data:`CONTACT_SIDE`) so that the score does not depend on the upload's size.

Each score has a threshold set on the world's validation renders for a stated false-alarm
rate (`ratouch train trust`, `ratouch.train.trust`); the calibration is a small JSON file
shipped beside the weights (`ratouch.paths.trust_calibration`).
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ratouch.errors import ConfigError, DataError, DataNotFoundError
from ratouch.files import write_atomic
from ratouch.images import check_background_size, gaussian_blur, resize_array
from ratouch.model.geometry import (
    BAND_FACTOR,
    BAND_FAMILIES,
    FIELD_CHECK_FAMILIES,
    GeometryCalibration,
    HeightMap,
    band_stats,
    read_height,
)
from ratouch.model.markers import MIN_FOUND, background_markers
from ratouch.world.sensors import WITHHOLD_LIMIT, guess_family, unfamiliar_look

log = logging.getLogger(__name__)

#: Longer side (pixels) frames are resized to before the contact score (the world's frames
#: are 128 x 96, a DIGIT's 320 x 240).
CONTACT_SIDE = 128
#: Blur sigmas (working-resolution pixels) of the contact score: noise, illumination field.
NOISE_SIGMA = 1.0
FIELD_SIGMA = 8.0
FORMAT = "ratouch-trust-3"
#: What the contact reading of a frame can be.
CONTACT_STATES = ("contact", "no contact", "uncertain")
#: Band-pass pairs (working-resolution sigmas) the contact model reads.
CONTACT_BANDS = ((0.7, 2.0), (1.5, 4.0), (3.0, 8.0))


# --------------------------------------------------------------------------- novelty

#: Spatial spread (:func:`image_spread`, grey levels of 255) below which a visual crop is
#: uniform, a blank or a flat colour: nothing to recognise, never familiar, whatever its
#: embedding's distance (a plain white photo sits near the renders' mean). Below every one of
#: 1,002 world crops (test[0:402] and train[0:600] of world seed 0: smallest 1.43, 1st
#: percentile 3.3) and above a flat photo with strong pixel noise (std 8 levels: 0.43).
UNIFORM_SPREAD = 1.0


def image_spread(crop: np.ndarray) -> float:
    """How much a visual crop (uint8 RGB) varies in space: the std of its grey levels (of
    255) at 64 pixels on its longer side, where area averaging has removed pixel noise."""
    h, w = crop.shape[:2]
    s = 64 / max(h, w)
    small = resize_array(crop, (max(1, round(w * s)), max(1, round(h * s))))
    grey = small.astype(np.float64) @ np.array([0.299, 0.587, 0.114])  # (h', w')
    return float(grey.std())


@dataclass(frozen=True)
class Novelty:
    """A probabilistic-PCA distance from a reference set of embeddings, and its threshold.

    Attributes:
        mean: (D,) mean of the reference embeddings.
        components: (r, D) top principal directions (rows, unit length).
        variances: (r,) variance of the reference along each direction.
        residual: mean variance per dimension of what the r directions leave.
        threshold: scores above it are flagged as novel.
    """

    mean: np.ndarray
    components: np.ndarray
    variances: np.ndarray
    residual: float
    threshold: float = float("inf")

    @classmethod
    def fit(cls, reference: np.ndarray, rank: int = 16) -> Novelty:
        """Fit the distance to (N, D) reference embeddings (threshold left at +inf)."""
        X = np.asarray(reference, np.float64)
        if X.ndim != 2 or len(X) <= rank:
            raise ConfigError(f"novelty: need an (N, D) reference with N > rank={rank}, "
                              f"got shape {X.shape}")
        mean = X.mean(0)
        _, s, vt = np.linalg.svd(X - mean, full_matrices=False)
        var = s ** 2 / (len(X) - 1)
        residual = float(var[rank:].sum() / max(1, X.shape[1] - rank))
        return cls(mean, vt[:rank], var[:rank], max(residual, 1e-12))

    def score(self, X: np.ndarray) -> np.ndarray:
        """(N,) distances of (N, D) embeddings; about 1 for typical reference points."""
        d = np.asarray(X, np.float64) - self.mean  # (N, D)
        z = d @ self.components.T  # (N, r)
        resid = (d * d).sum(1) - (z * z).sum(1)
        m2 = (z * z / self.variances).sum(1) + np.maximum(resid, 0) / self.residual
        return np.sqrt(m2 / self.mean.shape[0])

    def with_threshold(self, threshold: float) -> Novelty:
        return Novelty(self.mean, self.components, self.variances, self.residual,
                       float(threshold))

    def to_dict(self) -> dict:
        return {"mean": _floats(self.mean), "components": [_floats(c) for c in self.components],
                "variances": _floats(self.variances), "residual": self.residual,
                "threshold": self.threshold}

    @classmethod
    def from_dict(cls, d: dict) -> Novelty:
        return cls(np.asarray(d["mean"], np.float64), np.asarray(d["components"], np.float64),
                   np.asarray(d["variances"], np.float64), float(d["residual"]),
                   float(d["threshold"]))


def _floats(a: np.ndarray) -> list[float]:
    return [float(f"{v:.6g}") for v in np.asarray(a).ravel()]


# --------------------------------------------------------------------------- contact

def _working(frame: np.ndarray, size: tuple[int, int] | None = None) -> np.ndarray:
    """A uint8 frame as float [0, 1] at the working resolution (or at `size`, (W, H))."""
    h, w = frame.shape[:2]
    if size is None:
        scale = CONTACT_SIDE / max(h, w)
        size = (max(8, round(w * scale)), max(8, round(h * scale)))
    return resize_array(frame, size, reducing_gap=2.0).astype(np.float32) / 255.0


#: Blocks (rows, columns) the band energies are pooled over: contact is local (a patch), a
#: sensor's own structure (marker dots, grain, noise) is spread over the whole gel.
CONTACT_BLOCKS = (6, 8)


def contact_features(frame: np.ndarray, background: np.ndarray | None = None) -> np.ndarray:
    """The contact model's input: log statistics of a frame's band-passes (or of its
    difference from the sensor's background), at the working resolution.

    Args:
        frame: (H, W, 3) uint8 tactile frame.
        background: the same sensor's no-contact frame, (H, W, 3) uint8, or None.

    Returns:
        (F,) float64: per band of :data:`CONTACT_BANDS`, log RMS and log 99th percentile of
        |band| and how concentrated its energy is over :data:`CONTACT_BLOCKS` (log max and
        log 80th percentile of the block energies over their median); the finest detail's
        log RMS (noise level); the frame's mean colour (which sensor it is); with a
        background also the log RMS and 99th percentile of the lightly blurred difference.

    Raises:
        DataError: If the background's size differs from the frame's.
    """
    f = _working(frame)
    colour = f.mean((0, 1))
    if background is not None:
        check_background_size(background.shape[1::-1], frame.shape[1::-1], "the background")
        f = f - _working(background, (f.shape[1], f.shape[0]))
    eps = 1e-4
    sigmas = sorted({x for b in CONTACT_BANDS for x in b} | {NOISE_SIGMA})
    blurred = {s: gaussian_blur(f, s) for s in sigmas}
    gh, gw = CONTACT_BLOCKS
    feats: list[float] = []
    for lo, hi in CONTACT_BANDS:
        band = np.abs(blurred[lo] - blurred[hi]).mean(2)
        feats += [np.log(np.sqrt(np.mean(band * band)) + eps),
                  np.log(np.percentile(band, 99) + eps)]
        h, w = band.shape[0] // gh * gh, band.shape[1] // gw * gw
        blocks = band[:h, :w].reshape(gh, h // gh, gw, w // gw).transpose(0, 2, 1, 3)
        energy = np.sqrt((blocks.reshape(gh * gw, -1) ** 2).mean(1))
        med = np.median(energy) + eps
        # eps on both sides: a frame equal to its background has no energy at all
        feats += [np.log((energy.max() + eps) / med),
                  np.log((np.percentile(energy, 80) + eps) / med)]
    fine = f - blurred[NOISE_SIGMA]
    feats.append(np.log(np.sqrt(np.mean(fine * fine)) + eps))
    feats += [float(c) for c in colour]
    if background is not None:
        low = np.abs(blurred[NOISE_SIGMA] - blurred[NOISE_SIGMA].mean((0, 1)))
        feats += [np.log(np.sqrt(np.mean(low * low)) + eps), np.log(np.percentile(low, 99) + eps)]
    return np.asarray(feats, np.float64)


#: Indices in :func:`contact_features` (no background) of the terms that scale with the
#: frame's brightness: each band's log RMS and log 99th percentile, and the finest detail's log
#: RMS. The block-concentration terms are ratios already; the last three are the mean colour.
_LEVEL_TERMS = (0, 1, 4, 5, 8, 9, 12)
#: How many of :func:`contact_features`' numbers (no background) come before the mean colour.
_BEFORE_COLOUR = 13


def contact_features_free(frame: np.ndarray) -> np.ndarray:
    """The contact model's input for a frame alone, blind to the sensor's colours:
    :func:`contact_features` without the frame's mean colour, its level terms (band RMS and
    percentiles, the noise level) relative to the log of the frame's mean level, so that a
    sensor with other LEDs or gains reads as a rendered one does. (13,) float64."""
    x = contact_features(frame)[:_BEFORE_COLOUR].copy()
    x[list(_LEVEL_TERMS)] -= float(np.log(_working(frame).mean() + 1e-3))
    return x


def background_change(frame: np.ndarray, background: np.ndarray) -> float:
    """How much a frame differs from its sensor's no-contact frame beyond a global brightness
    drift: the 99th percentile of the lightly blurred |difference| (mean over channels, per
    channel's mean difference removed), [0, 1] units at the working resolution.

    A frame equal to its background within sensor noise scores at the noise's level; the
    calibration's `noise_floor` (set on no-contact renders) is the bound.

    Raises:
        DataError: If the background's size differs from the frame's.
    """
    check_background_size(background.shape[1::-1], frame.shape[1::-1], "the background")
    f = _working(frame)
    d = f - _working(background, (f.shape[1], f.shape[0]))
    d = gaussian_blur(d - d.mean((0, 1)), NOISE_SIGMA)
    return float(np.percentile(np.abs(d).mean(2), 99))


def _quadratic(z: np.ndarray) -> np.ndarray:
    """(N, F) -> (N, F + F(F+1)/2): the features and their pairwise products (so that a
    linear model can weigh a statistic differently for each kind of sensor)."""
    i, j = np.triu_indices(z.shape[1])
    return np.concatenate([z, z[:, i] * z[:, j]], axis=1)


@dataclass(frozen=True)
class ContactModel:
    """A logistic model of "contact" over the standardised :func:`contact_features` and
    their pairwise products.

    Attributes:
        mean, scale: the features' standardisation.
        coef, intercept: the logistic model over `_quadratic` of the standardised features;
            its logit is the contact score.
    """

    mean: np.ndarray
    scale: np.ndarray
    coef: np.ndarray
    intercept: float

    @classmethod
    def fit(cls, contact: np.ndarray, no_contact: np.ndarray, c: float = 0.1) -> ContactModel:
        """Fit on (N, F) features of frames with and (M, F) without contact (`c`: inverse
        L2 strength; the strongest regularisation tried, 0.1, separated the validation
        renders as well as 1 and 10)."""
        from sklearn.linear_model import LogisticRegression

        X = np.concatenate([contact, no_contact])
        y = np.r_[np.ones(len(contact)), np.zeros(len(no_contact))]
        mean, scale = X.mean(0), X.std(0) + 1e-9
        lr = LogisticRegression(C=c, max_iter=5000).fit(_quadratic((X - mean) / scale), y)
        return cls(mean, scale, lr.coef_[0].astype(np.float64), float(lr.intercept_[0]))

    def score(self, feats: np.ndarray) -> np.ndarray:
        """Contact logits of (N, F) features (higher: more surely contact)."""
        z = (np.atleast_2d(feats) - self.mean) / self.scale
        return _quadratic(z) @ self.coef + self.intercept

    def to_dict(self) -> dict:
        return {"mean": _floats(self.mean), "scale": _floats(self.scale),
                "coef": _floats(self.coef), "intercept": self.intercept}

    @classmethod
    def from_dict(cls, d: dict) -> ContactModel:
        return cls(np.asarray(d["mean"], np.float64), np.asarray(d["scale"], np.float64),
                   np.asarray(d["coef"], np.float64), float(d["intercept"]))


# --------------------------------------------------------------------------- the calibration

@dataclass(frozen=True)
class TrustCalibration:
    """Novelty distances for both modalities and the contact models with their thresholds,
    with how they were obtained (`meta`: data, seed, rates measured at calibration time).

    Attributes:
        encoder: the encoder the embeddings come from.
        visual, tactile: the novelty distances of the embeddings.
        visual_prior: the visual novelty in the frozen prior's feature space (None: the
            encoder has no prior; `visual` is used).
        contact, contact_bg: the contact models without and with a background frame.
        contact_threshold, contact_threshold_bg: frames whose contact logit is below it have
            no contact.
        meta: provenance and measured rates.
        noise_floor: a frame whose `background_change` is below it is its background within
            sensor noise: no contact, whatever the model says.
        uncertain: without a background, the contact logits (low, high) between which the
            model cannot decide (set on renders: below `low` lie few presses, above `high`
            few empty frames); a frame there is "uncertain".
        uncertain_alone: without a background, per sensor family, the lowest contact logit
            below the threshold that is still "uncertain" rather than "no contact": above
            what blank frames of that family score alone (set on drifted blank renders,
            `ratouch.train.trust.alone_band`), for frames that look like that family's units
            (`guess_family` within `LOOK_LIMIT`). A shallow, broad press that the model,
            fitted on firm presses, scores below its threshold is then answered with a
            caveat, not silenced; a blank frame still reads "no contact". None: no band.
        press_alone: without a background, per sensor family, a model of "a press of any
            kind (everyday presses: shallow, broad, textured; the world's) against a blank
            frame" read alone, and the edge of its logit above which a frame of that family
            is "uncertain" too (`ratouch.train.trust.with_alone_band`): the band widened by
            a second reading, for a family where the disc-press model's logit leaves many
            presses below its edge. None: none.
        contact_unfamiliar: without a background, for a frame that lies beyond every
            rendered unit (`guess_family` beyond `WITHHOLD_LIMIT`), the contact model blind
            to colour and its threshold that decide instead of `contact`. None: none.
    """

    encoder: str
    visual: Novelty
    tactile: Novelty
    contact: ContactModel
    contact_bg: ContactModel
    contact_threshold: float
    contact_threshold_bg: float
    visual_prior: Novelty | None = None
    meta: dict = field(default_factory=dict)
    noise_floor: float = 0.0
    uncertain: tuple[float, float] | None = None
    uncertain_alone: dict[str, float] | None = None
    press_alone: dict[str, tuple[ContactModel, float]] | None = None
    #: the sensor families' geometry lookups and structured-change floors (shipped beside,
    #: not inside, this file: `ratouch.paths.geometry_calibration`); None: not loaded
    geometry: GeometryCalibration | None = None
    #: without a background, for a frame beyond every rendered unit (`unfamiliar_look` at
    #: `WITHHOLD_LIMIT`): a contact model on `contact_features_free` (blind to the sensor's
    #: colours) and its threshold (`ratouch.train.trust.with_unfamiliar_contact`); None: such
    #: a frame is read by `contact` like any other
    contact_unfamiliar: tuple[ContactModel, float] | None = None

    def save(self, path: str | os.PathLike) -> Path:
        """Write the calibration as JSON (atomically; the vectors one per line)."""
        head = {"format": FORMAT, "encoder": self.encoder, "meta": self.meta,
                "contact_threshold": self.contact_threshold,
                "contact_threshold_bg": self.contact_threshold_bg,
                "noise_floor": self.noise_floor,
                "uncertain": None if self.uncertain is None else list(self.uncertain),
                "uncertain_alone": self.uncertain_alone,
                "press_alone": None if self.press_alone is None else {
                    k: {"model": m.to_dict(), "edge": e}
                    for k, (m, e) in self.press_alone.items()},
                "contact_unfamiliar": None if self.contact_unfamiliar is None else {
                    "model": self.contact_unfamiliar[0].to_dict(),
                    "threshold": self.contact_unfamiliar[1]},
                "contact": self.contact.to_dict(), "contact_bg": self.contact_bg.to_dict()}
        lines = [json.dumps(head, indent=1)[:-2] + ","]
        models = [("visual", self.visual), ("tactile", self.tactile)]
        if self.visual_prior is not None:
            models.append(("visual_prior", self.visual_prior))
        for n, (name, model) in enumerate(models):
            d = model.to_dict()
            lines.append(f' "{name}": {{')
            lines.append(",\n".join(f'  "{k}": {json.dumps(v)}' for k, v in d.items()))
            lines.append(" }" + ("," if n < len(models) - 1 else ""))
        return write_atomic(path, "\n".join(lines) + "\n}\n")

    @classmethod
    def load(cls, path: str | os.PathLike) -> TrustCalibration:
        """Read a calibration written by `save`.

        Raises:
            DataNotFoundError: the file does not exist.
            DataError: it is not a trust calibration.
        """
        path = Path(path)
        if not path.is_file():
            raise DataNotFoundError(f"no trust calibration at {path} (`ratouch train trust`)")
        try:
            d = json.loads(path.read_text(encoding="utf-8"))
            if d.get("format") != FORMAT:
                raise ValueError(f"format {d.get('format')!r}, expected {FORMAT!r}")
            prior = d.get("visual_prior")
            band = d.get("uncertain")
            alone = d.get("uncertain_alone")
            if alone is not None and not isinstance(alone, dict):
                raise ValueError(f"uncertain_alone must map sensor families to logits, got "
                                 f"{type(alone).__name__}")
            foreign = d.get("contact_unfamiliar")
            if foreign is not None and not isinstance(foreign, dict):
                raise ValueError(f"contact_unfamiliar must be a model and its threshold, got "
                                 f"{type(foreign).__name__}")
            pressed = d.get("press_alone")
            if pressed is not None and not isinstance(pressed, dict):
                raise ValueError(f"press_alone must map sensor families to models, got "
                                 f"{type(pressed).__name__}")
            return cls(d["encoder"], Novelty.from_dict(d["visual"]),
                       Novelty.from_dict(d["tactile"]), ContactModel.from_dict(d["contact"]),
                       ContactModel.from_dict(d["contact_bg"]), float(d["contact_threshold"]),
                       float(d["contact_threshold_bg"]),
                       None if prior is None else Novelty.from_dict(prior), d.get("meta", {}),
                       float(d["noise_floor"]),
                       None if band is None else (float(band[0]), float(band[1])),
                       None if alone is None else {str(k): float(v) for k, v in alone.items()},
                       None if pressed is None else {
                           str(k): (ContactModel.from_dict(v["model"]), float(v["edge"]))
                           for k, v in pressed.items()},
                       contact_unfamiliar=None if foreign is None else (
                           ContactModel.from_dict(foreign["model"]),
                           float(foreign["threshold"])))
        except (ValueError, KeyError, TypeError) as e:
            raise DataError(f"{path} is not a trust calibration: {e}") from e

    def contact_score(self, frame: np.ndarray, background: np.ndarray | None = None) -> float:
        """The contact logit of one frame (with its background's model where one is given)."""
        model = self.contact if background is None else self.contact_bg
        return float(model.score(contact_features(frame, background))[0])

    def reads_unfamiliar(self, look: tuple[str, float]) -> bool:
        """Whether a frame read without a background, whose `guess_family` answer is `look`,
        is decided by the colour-blind `contact_unfamiliar` (it lies beyond every rendered
        unit, `WITHHOLD_LIMIT`, and the calibration has that model)."""
        return self.contact_unfamiliar is not None and unfamiliar_look(look, WITHHOLD_LIMIT)

    def unfamiliar_score(self, frame: np.ndarray) -> float:
        """The colour-blind contact logit of a frame alone (`contact_unfamiliar`).

        Raises:
            ConfigError: the calibration has no such model.
        """
        if self.contact_unfamiliar is None:
            raise ConfigError("this trust calibration has no colour-blind contact model "
                              "(`ratouch train trust --unfamiliar`)")
        return float(self.contact_unfamiliar[0].score(contact_features_free(frame))[0])

    def structured_contact(self, frame: np.ndarray, background: np.ndarray,
                           family: str | None = None) -> dict | None:
        """Contact by structured local change against the background, with the floors of
        `family` (default: guessed from the frame): {"contact", "score", "threshold",
        "family"}; None when no geometry calibration (or lookup for the family) is loaded."""
        read = self.read_geometry(frame, background, family, height=False)
        return None if read is None else read["structure"]

    def height_map(self, frame: np.ndarray, background: np.ndarray,
                   family: str | None = None) -> HeightMap | None:
        """The frame read as geometry against its background by `family`'s lookup (default:
        guessed from the frame), or None (no geometry calibration or lookup)."""
        read = self.read_geometry(frame, background, family)
        return None if read is None else read["height"]

    def read_geometry(self, frame: np.ndarray, background: np.ndarray,
                      family: str | None = None, height: bool = True,
                      look: tuple[str, float] | None = None) -> dict | None:
        """The frame's drift-free change against its background, computed once, read both
        ways: {"structure": the structured-contact block, "height": its `HeightMap` and
        "firmness": the family's firmness reading of it (`GeometryCalibration.read_firmness`;
        both None unless `height`, the firmness None where the family has no model)}; None
        when no geometry calibration or lookup for the family. A frame beyond every rendered
        unit (`WITHHOLD_LIMIT`) is held to the lookup's floors for such a sensor where it has
        them (the block's "floors": "unfamiliar sensor"; else "family").
        `look`: `guess_family(frame)` where the caller already has it."""
        if self.geometry is None:
            return None
        check_background_size(background.shape[1::-1], frame.shape[1::-1], "the background")
        look = guess_family(frame) if look is None else look
        name = look[0] if family is None else family
        lookup = self.geometry.lookup(name)
        if lookup is None:
            return None
        change, noise = lookup.change_and_noise(frame, background)
        stats = band_stats(change)  # read by the contact check and the firmness model
        # floors set on one family's units say nothing of a sensor unlike all of them
        beyond = unfamiliar_look(look, WITHHOLD_LIMIT) and bool(lookup.unfamiliar_floors)
        hit, score = lookup.contact(frame, background, change, stats, unfamiliar=beyond,
                                    noise=noise)
        hm = read_height(lookup, frame, background, change) if height else None
        threshold = lookup.floors_for(beyond)[1]
        structure: dict[str, Any] = {"contact": hit, "score": round(score, 3) if np.isfinite(score) else None,
                     "threshold": round(threshold, 3), "family": name,
                     "floors": "unfamiliar sensor" if beyond else "family"}
        field = (lookup.field_reading(frame, background)
                 if hit and not beyond and name in FIELD_CHECK_FAMILIES else None)
        if hit and not beyond and name in BAND_FAMILIES:
            # a change barely above what this family's blanks show against another unit's
            # background: read, with a caveat (docs/geometry.md)
            top = BAND_FACTOR * threshold  # the family's: not beyond
            structure["band"] = {"top": round(top, 3), "inside": bool(score <= top)}
        if field is not None:
            # a second reading: does a smooth lighting field alone explain the change?
            structure["lighting_field"] = {
                "score": round(field[1], 3) if np.isfinite(field[1]) else None,
                "threshold": round(lookup.field_threshold, 3), "explains": field[0]}
        return {"structure": structure,
                "height": hm,
                "firmness": (None if hm is None else
                             self.geometry.read_firmness(name, hm, change, stats))}

    def contact_state(self, frame: np.ndarray, background: np.ndarray | None = None,
                      structured: dict | None = None,
                      look: tuple[str, float] | None = None,
                      markers: dict | None | str = "read") -> tuple[str, float]:
        """What the frame shows, one of :data:`CONTACT_STATES`, and its contact logit.

        With a background whose marker dots the frame mostly does not show, or without any
        against a frame that shows a marker grid of its own
        (`model.markers.background_markers`: another unit's no-contact frame, or the gel
        moved): "uncertain", whatever else it shows. Otherwise, with a background: a frame whose structured local change (edges and texture, the
        sensor's global drift removed) stands above its family's floors is "contact"
        (`structured_contact`: shallow, broad presses that change a few levels), or
        "uncertain" where the block's `lighting_field` says a smooth lighting field alone
        explains it (`geometry.FIELD_CHECK_FAMILIES`: another unit's background) or its
        `band` says it is barely above the threshold (`geometry.BAND_FAMILIES`: within
        `BAND_FACTOR` x the threshold, where a blank against another unit's background can
        reach); otherwise a
        frame within sensor noise of it (`noise_floor`) is "no contact" by construction,
        and else the model decides at `contact_threshold_bg`; for a frame beyond every
        rendered unit, held to such a sensor's floors (`GradientLookup.unfamiliar_floors`),
        the model, which reads the frame's colours, makes it "uncertain", never "contact".
        Without:
        the model decides outside the `uncertain` band and says "uncertain" inside it, and
        above its threshold for a frame beyond every rendered unit (its "contact" there is
        read from colours it was never fitted on), and
        below its threshold but above what the frame's family's blank frames score alone
        (`uncertain_alone`), or above what they score on the family's `press_alone` model
        (for a frame that looks like that family's units) too (a frame that looks like none of the
        rendered sensors is flagged by `assess`, not here); a frame beyond every rendered unit
        is decided by the colour-blind model instead (`reads_unfamiliar`), without a band, and
        the score returned is its logit. A score that is not a finite
        number is never "contact": it is "uncertain".
        `structured`: the `structured_contact` block where the caller already has it;
        `look`: `guess_family(frame)` where the caller already has it; `markers`:
        `background_markers(frame, background)` where the caller already has it ("read":
        read here).
        """
        if background is not None:
            marks = background_markers(frame, background) if isinstance(markers, str) \
                else markers
            if marks is not None and marks["moved"]:
                return "uncertain", float(self.contact_score(frame, background))
            if structured is None:
                read = self.read_geometry(frame, background, height=False, look=look)
                structured = None if read is None else read["structure"]
            if structured is not None and structured["contact"]:
                # a change a smooth lighting field alone explains: another unit's background,
                # or light that changed, as likely as a press; read, with a caveat
                field = structured.get("lighting_field") or {}
                band = structured.get("band") or {}
                return (("uncertain" if field.get("explains") or band.get("inside")
                         else "contact"),
                        float(self.contact_score(frame, background)))
            if background_change(frame, background) < self.noise_floor:
                return "no contact", float(self.contact_score(frame, background))
        if background is None and self.contact_unfamiliar is not None:
            look = guess_family(frame) if look is None else look  # read only where it decides
            if self.reads_unfamiliar(look):
                # a sensor unlike every rendered unit: its colours say nothing the disc-press
                # model was fitted on, so contact is read blind to them
                assert self.contact_unfamiliar is not None  # reads_unfamiliar checked it
                score = self.unfamiliar_score(frame)
                if not np.isfinite(score):
                    return "uncertain", score
                return ("contact" if score >= self.contact_unfamiliar[1] else "no contact"), score
        score = self.contact_score(frame, background)
        if not np.isfinite(score):
            return "uncertain", score
        if background is not None:
            if score < self.contact_threshold_bg:
                return "no contact", score
            # beyond every rendered unit the model reads colours it was never fitted on:
            # where the structured change (held to such a sensor's floors) found nothing,
            # its "contact" is a guess
            unsure = structured is not None and structured.get("floors") == "unfamiliar sensor"
            return ("uncertain" if unsure else "contact"), score
        if self.uncertain is not None and self.uncertain[0] <= score < self.uncertain[1]:
            return "uncertain", score
        if score >= self.contact_threshold:
            look = guess_family(frame) if look is None else look
            # beyond every rendered unit the disc-press model reads colours it was never
            # fitted on: there, recoloured blank renders score above nearly every recoloured
            # press (docs/geometry.md), so its "contact" is a guess
            return ("uncertain" if unfamiliar_look(look, WITHHOLD_LIMIT) else "contact"), score
        # the band of the family the frame looks like, where it looks like one: a band set
        # on one family's blanks says nothing of a sensor that looks like none of them
        return ("uncertain" if self.alone_band_reading(frame, score, look) else "no contact"), score

    def second_opinion(self, frame: np.ndarray, background: np.ndarray | None, state: str
                       ) -> dict | None:
        """Where the contact against a background is "uncertain" (`state`): the frame read
        alone, {"state", "contact"} (`contact_state(frame, None)`; "contact" None when not a
        number); else None. Where it shows no contact alone either, the touch may be a
        blank's read against the wrong background (`doubts_touch`)."""
        if background is None or state != "uncertain":
            return None
        st, score = self.contact_state(frame, None)
        return {"state": st, "contact": round(score, 4) if np.isfinite(score) else None}

    def alone_band_reading(self, frame: np.ndarray, score: float,
                           look: tuple[str, float] | None = None) -> dict | None:
        """Without a background, for a frame whose contact logit `score` is below the
        threshold: the reading of its family's band that finds it above what that family's
        blank frames score alone, {"family", "reading" ("contact model" or "press model"),
        "score", "edge"}; None when neither does or the frame looks like no family's units
        (`look`: `guess_family(frame)` where the caller has it)."""
        name, distance = guess_family(frame) if look is None else look
        if unfamiliar_look((name, distance)):
            return None
        low = (self.uncertain_alone or {}).get(name)
        if low is not None and score >= low:
            return {"family": name, "reading": "contact model", "score": round(score, 3),
                    "edge": low}
        pressed = (self.press_alone or {}).get(name)
        if pressed is not None:
            read = float(pressed[0].score(contact_features(frame))[0])
            if read >= pressed[1]:
                return {"family": name, "reading": "press model", "score": round(read, 3),
                        "edge": pressed[1]}
        return None

    def visual_novelty(self, V: np.ndarray, prior: np.ndarray | None = None) -> dict:
        """The visual novelty block: in the prior's feature space where both the calibration
        and the features have one, else of the embedding."""
        if self.visual_prior is not None and prior is not None:
            return {**_novelty_block(self.visual_prior, prior), "space": "prior"}
        return {**_novelty_block(self.visual, V), "space": "embedding"}

    def assess(self, V: np.ndarray, T: np.ndarray | None, frame: np.ndarray | None,
               background: np.ndarray | None = None, prior: np.ndarray | None = None,
               crop: np.ndarray | None = None) -> dict:
        """The trust block of one query.

        Args:
            V: (1, D) visual embedding.
            T: (1, D) tactile embedding, or None (no tactile image).
            frame: the tactile frame (uint8), or None.
            background: the sensor's no-contact frame, or None.
            prior: (1, F) the visual prior's features of the crop, or None.
            crop: the visual crop (uint8): a uniform one (:data:`UNIFORM_SPREAD`) is novel.

        Returns:
            {"visual": {"novelty", "threshold", "novel", "space", and with a crop
            "uniform"}, "tactile": {... plus
            "contact" (None when not a number), "contact_threshold", "state",
            "no_contact", "uncertain", "background", "sensor" (the family read, guessed from the
            frame's colours), "unfamiliar_sensor", and with a background "structure",
            "geometry" and "firmness" (read from shape; None for no contact), and
            "within_noise" ({"change", "floor"}) where the frame was called no contact for
            being its background within the sensor's noise, though the contact model would
            have said contact, and "alone" ({"state", "contact"}: the frame read without the
            background, `second_opinion`) where the contact against the background is
            "uncertain"} or None,
            "warnings": [...],
            "height_map": the frame's `HeightMap` against the background (an object, not
            JSON: its numbers are "geometry"), or None}
        """
        out: dict[str, Any] = {"visual": self.visual_novelty(V, prior), "tactile": None,
                               "height_map": None}
        warnings = []
        spread = None if crop is None else image_spread(crop)
        if spread is not None:
            out["visual"]["uniform"] = spread < UNIFORM_SPREAD
        if out["visual"].get("uniform"):
            out["visual"]["novel"] = True
            warnings.append(
                f"uniform image: nothing to recognise (the visual crop's grey levels vary by "
                f"{spread:.2f} of 255, unlike the images the encoders were trained on): its "
                "neighbours and descriptions are guesses")
        elif out["visual"]["novel"]:
            warnings.append(
                f"the visual crop is unlike the images the encoders were trained on (novelty "
                f"{out['visual']['novelty']} > {out['visual']['threshold']})")
        if T is not None and frame is not None:
            tac = _novelty_block(self.tactile, T)
            # the family the frame was read as, guessed once from its colours
            name, distance = guess_family(frame)
            blind = background is None and self.reads_unfamiliar((name, distance))
            thr = (self.contact_threshold if background is None else self.contact_threshold_bg)
            if blind:
                assert self.contact_unfamiliar is not None  # reads_unfamiliar checked it
                thr = self.contact_unfamiliar[1]
            read = (None if background is None else
                    self.read_geometry(frame, background, name, look=(name, distance)))
            marks = None if background is None else background_markers(frame, background)
            state, score = self.contact_state(
                frame, background, None if read is None else read["structure"],
                (name, distance), marks)
            tac.update({"contact": round(score, 4) if np.isfinite(score) else None,
                        "contact_threshold": round(thr, 4), "state": state,
                        "no_contact": state == "no contact", "uncertain": state == "uncertain",
                        "background": background is not None,
                        # which contact model read the frame alone: blind to colour beyond
                        # every rendered unit, else the disc-press model
                        "contact_model": None if background is not None else (
                            "colour-blind" if blind else "disc-press")})
            if marks is not None:
                tac["markers"] = marks
            alone = self.second_opinion(frame, background, state)
            if alone is not None:
                tac["alone"] = alone
            if background is not None and self.geometry is not None:
                tac["structure"] = None if read is None else read["structure"]
                tac["geometry"] = None if read is None else read["height"].to_dict()
                out["height_map"] = None if read is None else read["height"]
                # firmness from shape: a reading of a press, none of a blank
                tac["firmness"] = (None if read is None or state == "no contact"
                                   else read["firmness"])
            if (background is not None and state == "no contact" and np.isfinite(score)
                    and score >= thr):
                # the model would say contact: the frame was called its background because it
                # is that background within the sensor's noise (`contact_state`'s noise floor)
                tac["within_noise"] = {
                    "change": round(background_change(frame, background), 4),
                    "floor": round(self.noise_floor, 4)}
            unlike = unfamiliar_look((name, distance))
            tac["sensor"] = {"family": name, "distance": round(distance, 3), "source": (
                "the nearest guess: the frame looks like none of the families' units"
                if unlike else "guessed from the frame's colours")}
            # a frame unlike every rendered sensor: without a background the contact model
            # reads its own look (a guess); with one the contact is read against it, but the
            # encoders have never seen such a sensor: the description is a guess either way
            foreign = unlike
            tac["unfamiliar_sensor"] = bool(foreign)
            out["tactile"] = tac
            against = ", against the background frame" if background is not None else ""
            if tac["no_contact"]:
                noise = tac.get("within_noise")
                shown = "" if tac["contact"] is None else (
                    f" (it differs from the background frame by {noise['change']}, within "
                    f"the sensor's noise: < {noise['floor']})" if noise else
                    f" (contact {tac['contact']} < {tac['contact_threshold']}{against})")
                if tac.get("structure"):
                    shown += (f"; structured change {tac['structure']['score']} <= "
                              f"{tac['structure']['threshold']}")
                # read alone, a shallow, broad press (a fabric, foam, tape) can look like
                # the gel at rest: say what reads it (docs/geometry.md)
                remedy = "" if background is not None else (
                    "; if something is pressed into it, give the sensor's no-contact frame "
                    "(background): against it, shallow and broad presses are found")
                warnings.append(
                    "no contact detected: the tactile image looks like the sensor's "
                    f"background with nothing pressed into it{shown}; no material "
                    f"description is given{remedy}")
            elif tac["uncertain"] and marks is not None and marks.get("lattice"):
                tac["uncertain_by"] = None
                grid = marks["lattice"]
                warnings.append(
                    f"contact uncertain: the frame shows a grid of {grid['dots']} marker dots "
                    f"(pitch {grid['pitch']:.1f} px) that the background lacks: markers are "
                    "printed on the gel, so the background looks like another unit's; give "
                    "this unit's background taken now; the description below is a guess")
            elif tac["uncertain"] and marks is not None and marks["moved"]:
                tac["uncertain_by"] = None
                where = (f"the frame shows {marks['found']} of its {marks['dots']}"
                         if marks["share"] < MIN_FOUND else
                         f"the {marks['found']} of its {marks['dots']} the frame shows sit "
                         f"{marks['shift']:.1f} px off as a whole, where a press moves only "
                         "those it touches")
                warnings.append(
                    f"contact uncertain: the background's marker dots are not where this "
                    f"frame's are ({where}): it looks like another unit's no-contact frame, "
                    "or the gel has moved; give this unit's background taken now; the "
                    "description below is a guess")
            elif tac["uncertain"] and ((tac.get("structure") or {}).get("lighting_field")
                                       or {}).get("explains"):
                tac["uncertain_by"] = None
                st = tac["structure"]
                warnings.append(
                    f"contact uncertain: the change against the background is a smooth "
                    f"lighting field across the whole gel (structured change "
                    f"{st['score']} > {st['threshold']}, but {st['lighting_field']['score']} "
                    f"with the field removed): the background may be another unit's, or the "
                    "light changed; give this unit's background taken now; the description "
                    "below is a guess")
            elif tac["uncertain"] and ((tac.get("structure") or {}).get("band")
                                       or {}).get("inside"):
                tac["uncertain_by"] = None
                st = tac["structure"]
                warnings.append(
                    f"contact uncertain: the change against the background is barely above "
                    f"what a blank frame shows against it (structured change {st['score']} > "
                    f"{st['threshold']}, but within {st['band']['top']}, {BAND_FACTOR:g} x that): a "
                    "light touch, or another unit's background; give this unit's background "
                    "taken now; the description below is a guess")
            elif tac["uncertain"] and background is not None:
                tac["uncertain_by"] = None
                st = tac.get("structure") or {}
                warnings.append(
                    f"contact uncertain: the tactile frame looks like none of the sensors "
                    f"rendered (distance {distance:.2f}, beyond every rendered unit's "
                    f"{WITHHOLD_LIMIT:.2f}); against its background it shows no structured "
                    f"change above the floors set for such a sensor (structured change "
                    f"{st.get('score')} <= {st.get('threshold')}), and the contact model "
                    f"that says contact ({tac['contact']} >= {tac['contact_threshold']}) "
                    "reads colours no rendered unit has: the description below is a guess")
            elif tac["uncertain"]:
                by = (self.alone_band_reading(frame, score, (name, distance))
                      if background is None and np.isfinite(score) else None)
                tac["uncertain_by"] = by
                why = "" if by is None else (
                    f" (read alone, the {by['family']} {by['reading']} scores {by['score']} "
                    f">= {by['edge']}, above what its blank frames score)")
                if (by is None and background is None and np.isfinite(score)
                        and score >= self.contact_threshold
                        and unfamiliar_look((name, distance), WITHHOLD_LIMIT)):
                    why = (f" (the frame looks like none of the sensors rendered, distance "
                           f"{distance:.2f}, beyond every rendered unit's {WITHHOLD_LIMIT:.2f}: "
                           f"its contact {tac['contact']} >= {tac['contact_threshold']} is read "
                           "from colours the model was never fitted on, where blank frames "
                           "score as high as presses)")
                warnings.append(
                    "contact uncertain: give the sensor's no-contact frame (background); "
                    f"the description below is a guess{why}")
            if blind and not tac["uncertain"]:
                warnings.append(
                    f"the tactile frame looks like none of the sensors rendered (distance "
                    f"{distance:.2f}, beyond every rendered unit's {WITHHOLD_LIMIT:.2f}): "
                    f"contact was read blind to its colours, '{state}', a guess; give the "
                    "sensor's no-contact frame (background)" + (
                        "" if tac["no_contact"] else ", and read the description below as a "
                                                     "guess"))
            elif foreign and not tac["uncertain"] and background is None:
                warnings.append(
                    f"the tactile frame looks like none of the sensors the contact check was "
                    f"fitted on: '{state}' is a guess; give the sensor's no-contact frame "
                    "(background)" + ("" if tac["no_contact"] else
                                      ", and read the description below as a guess"))
            elif foreign and not tac["uncertain"]:
                own = (tac.get("structure") or {}).get("floors") == "unfamiliar sensor"
                floors = (f"with the floors set for such a sensor, through the nearest "
                          f"family's lookup, '{name}'" if own else
                          f"with the nearest family's floors, '{name}'")
                warnings.append(
                    "the tactile frame looks like none of the sensors the models were trained "
                    f"on (read against its background as '{state}', {floors})"
                    + ("" if tac["no_contact"] else ": read the description below as a guess"))
            elif tac["novel"]:
                warnings.append(
                    f"the tactile image is unlike the frames the encoders were trained on "
                    f"(novelty {tac['novelty']} > {tac['threshold']}): treat the neighbours "
                    "and descriptions as guesses")
        out["warnings"] = warnings
        return out


def doubts_touch(tactile: dict | None) -> bool:
    """Whether a trust block's tactile part (`TrustCalibration.assess`) doubts the touch
    itself: its contact against the background is "uncertain" and the frame read alone
    (`second_opinion`, "alone") is not "contact": as likely a blank read against another
    unit's background as a press (docs/premise.md, "Touch withheld where contact against the
    background is uncertain and the frame alone shows none")."""
    if not tactile or not tactile.get("alone"):
        return False
    return tactile.get("state") == "uncertain" and tactile["alone"]["state"] != "contact"


def _novelty_block(model: Novelty, X: np.ndarray) -> dict:
    score = float(model.score(X)[0])
    return {"novelty": round(score, 4), "threshold": round(model.threshold, 4),
            "novel": bool(score > model.threshold)}


def threshold_for(scores: Sequence[float] | np.ndarray, false_alarm: float, above: bool = True) -> float:
    """The threshold flagging a `false_alarm` share of in-distribution `scores`: the
    (1 - false_alarm) quantile when large scores are flagged (`above`), else the
    false_alarm quantile."""
    if not 0 < false_alarm < 1:
        raise ConfigError(f"false_alarm must lie in (0, 1), got {false_alarm}")
    q = 1 - false_alarm if above else false_alarm
    return float(np.quantile(np.asarray(scores, np.float64), q))
