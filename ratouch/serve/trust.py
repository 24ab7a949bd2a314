"""Trust signals for a query: how unlike the training data each input is, and whether the
tactile frame shows any contact at all.

* **Novelty** (per modality): a probabilistic-PCA Mahalanobis distance of the visual or
  tactile embedding from the embeddings of the world's training renders (the data the
  encoders were trained on): the top principal directions are whitened by their variances,
  the rest by the mean residual variance. Large means "unlike anything trained on": the
  retrieved neighbours and descriptions are then guesses.
* **No contact**: a tactile frame with nothing pressed into the gel is the sensor's
  background. With the background frame, the score is the RMS of (frame - background) after
  a light blur (sensor noise removed); without it, the RMS of the frame's band-pass
  (light blur minus heavy blur: the contact's shading, not the smooth illumination field).
  Both are computed at a fixed working resolution (:data:`CONTACT_SIDE`) so that the score
  does not depend on the upload's size.

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
from PIL import Image
from scipy.ndimage import gaussian_filter

from ratouch.errors import ConfigError, DataError, DataNotFoundError
from ratouch.files import write_atomic

log = logging.getLogger(__name__)

#: Longer side (pixels) frames are resized to before the contact score (the world's frames
#: are 128 x 96, a DIGIT's 320 x 240).
CONTACT_SIDE = 128
#: Blur sigmas (working-resolution pixels) of the contact score: noise, illumination field.
NOISE_SIGMA = 1.0
FIELD_SIGMA = 8.0
FORMAT = "ratouch-trust-1"


# --------------------------------------------------------------------------- novelty

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
    img = Image.fromarray(np.ascontiguousarray(frame))
    if img.size != size:
        img = img.resize(size, Image.Resampling.BILINEAR, reducing_gap=2.0)
    return np.asarray(img, np.float32) / 255.0


def contact_score(frame: np.ndarray, background: np.ndarray | None = None) -> float:
    """How much contact a tactile frame shows (higher: more), at the working resolution.

    Args:
        frame: (H, W, 3) uint8 tactile frame.
        background: the same sensor's no-contact frame, (H, W, 3) uint8, or None.

    Returns:
        100 x the RMS of the blurred difference from the background, or (no background) of
        the frame's band-pass between :data:`NOISE_SIGMA` and :data:`FIELD_SIGMA`.

    Raises:
        DataError: If the background's size differs from the frame's.
    """
    f = _working(frame)
    sig = (NOISE_SIGMA, NOISE_SIGMA, 0)
    if background is None:
        band = gaussian_filter(f, sig) - gaussian_filter(f, (FIELD_SIGMA, FIELD_SIGMA, 0))
        return float(100 * np.sqrt(np.mean(band * band)))
    if background.shape != frame.shape:
        raise DataError(
            f"background is {background.shape[1]}x{background.shape[0]} (WxH) but the tactile "
            f"image is {frame.shape[1]}x{frame.shape[0]}; the background must be the same "
            "sensor's no-contact frame at the same size")
    diff = gaussian_filter(f - _working(background, (f.shape[1], f.shape[0])), sig)
    return float(100 * np.sqrt(np.mean(diff * diff)))


# --------------------------------------------------------------------------- the calibration

@dataclass(frozen=True)
class TrustCalibration:
    """Novelty distances for both modalities and the no-contact thresholds, with how they
    were obtained (`meta`: data, seed, rates measured at calibration time).

    Attributes:
        encoder: the encoder the embeddings come from.
        visual, tactile: the novelty distances.
        contact_threshold: frames scoring below it (no background) have no contact.
        contact_threshold_bg: the same with a background frame.
        meta: provenance and measured rates.
    """

    encoder: str
    visual: Novelty
    tactile: Novelty
    contact_threshold: float
    contact_threshold_bg: float
    meta: dict = field(default_factory=dict)

    def save(self, path: str | os.PathLike) -> Path:
        """Write the calibration as JSON (atomically; the vectors one per line)."""
        head = {"format": FORMAT, "encoder": self.encoder, "meta": self.meta,
                "contact_threshold": self.contact_threshold,
                "contact_threshold_bg": self.contact_threshold_bg}
        lines = [json.dumps(head, indent=1)[:-2] + ","]
        for name, model in (("visual", self.visual), ("tactile", self.tactile)):
            d = model.to_dict()
            lines.append(f' "{name}": {{')
            lines.append(",\n".join(f'  "{k}": {json.dumps(v)}' for k, v in d.items()))
            lines.append(" }" + ("," if name == "visual" else ""))
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
            return cls(d["encoder"], Novelty.from_dict(d["visual"]),
                       Novelty.from_dict(d["tactile"]), float(d["contact_threshold"]),
                       float(d["contact_threshold_bg"]), d.get("meta", {}))
        except (ValueError, KeyError, TypeError) as e:
            raise DataError(f"{path} is not a trust calibration: {e}") from e

    def assess(self, V: np.ndarray, T: np.ndarray | None, frame: np.ndarray | None,
               background: np.ndarray | None = None) -> dict:
        """The trust block of one query.

        Args:
            V: (1, D) visual embedding.
            T: (1, D) tactile embedding, or None (no tactile image).
            frame: the tactile frame (uint8), or None.
            background: the sensor's no-contact frame, or None.

        Returns:
            {"visual": {"novelty", "threshold", "novel"}, "tactile": {... plus "contact",
            "contact_threshold", "no_contact", "background"} or None, "warnings": [...]}
        """
        out: dict[str, Any] = {"visual": _novelty_block(self.visual, V), "tactile": None}
        warnings = []
        if out["visual"]["novel"]:
            warnings.append(
                f"the visual crop is unlike the images the encoders were trained on (novelty "
                f"{out['visual']['novelty']} > {out['visual']['threshold']}): treat the "
                "neighbours and descriptions as guesses")
        if T is not None and frame is not None:
            tac = _novelty_block(self.tactile, T)
            thr = self.contact_threshold if background is None else self.contact_threshold_bg
            score = contact_score(frame, background)
            tac.update({"contact": round(score, 4), "contact_threshold": round(thr, 4),
                        "no_contact": bool(score < thr), "background": background is not None})
            out["tactile"] = tac
            if tac["no_contact"]:
                warnings.append(
                    f"no contact detected: the tactile image looks like the sensor's "
                    f"background with nothing pressed into it (contact {tac['contact']} < "
                    f"{tac['contact_threshold']}{', against the background frame' if background is not None else ''}); "
                    "no material description is given")
            elif tac["novel"]:
                warnings.append(
                    f"the tactile image is unlike the frames the encoders were trained on "
                    f"(novelty {tac['novelty']} > {tac['threshold']}): treat the neighbours "
                    "and descriptions as guesses")
        out["warnings"] = warnings
        return out


def _novelty_block(model: Novelty, X: np.ndarray) -> dict:
    score = float(model.score(X)[0])
    return {"novelty": round(score, 4), "threshold": round(model.threshold, 4),
            "novel": bool(score > model.threshold)}


def threshold_for(scores: Sequence[float], false_alarm: float, above: bool = True) -> float:
    """The threshold flagging a `false_alarm` share of in-distribution `scores`: the
    (1 - false_alarm) quantile when large scores are flagged (`above`), else the
    false_alarm quantile."""
    if not 0 < false_alarm < 1:
        raise ConfigError(f"false_alarm must lie in (0, 1), got {false_alarm}")
    q = 1 - false_alarm if above else false_alarm
    return float(np.quantile(np.asarray(scores, np.float64), q))
