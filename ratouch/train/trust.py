"""Calibrating the trust signals on the world alone (`ratouch train trust`).

Reference: the embeddings of training-split renders (indices the encoders were trained on).
Validation: training-split renders from indices far beyond those the encoders saw, the same
distribution but unseen; every threshold is set there for the requested false-alarm rate.
The test split is only measured (false alarms of each signal on its 402 pairs, and the
no-contact detection rate on the same pairs rendered without contact), never used to set a
threshold.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from tqdm import tqdm

from ratouch.errors import ConfigError
from ratouch.serve.trust import Novelty, TrustCalibration, contact_score, threshold_for
from ratouch.world.config import WorldConfig
from ratouch.world.generator import TEST_SIZE, World

log = logging.getLogger(__name__)

#: First training-split index of the validation renders: beyond any training run's pairs.
VALIDATION_START = 1_000_000


@dataclass(frozen=True)
class TrustConfig:
    """What `calibrate` renders and the false-alarm rate it targets.

    Attributes:
        seed: the world's seed.
        n_reference: training renders the novelty distances are fitted on.
        n_validation: unseen renders the thresholds are set on.
        false_alarm: share of in-distribution validation inputs each signal may flag.
        rank: principal directions kept by the novelty distances.
    """

    seed: int = 0
    n_reference: int = 2000
    n_validation: int = 1000
    false_alarm: float = 0.02
    rank: int = 16

    def __post_init__(self) -> None:
        for name in ("n_reference", "n_validation"):
            if getattr(self, name) < 50:
                raise ConfigError(f"{name}={getattr(self, name)} must be >= 50")
        if not 0 < self.false_alarm < 0.5:
            raise ConfigError(f"false_alarm={self.false_alarm} must lie in (0, 0.5)")
        if not 1 <= self.rank < self.n_reference:
            raise ConfigError(f"rank={self.rank} must lie in [1, n_reference)")


def _render(world: World, split: str, indices, progress: bool, what: str) -> dict:
    """Crops, tactile frames and their sensors' backgrounds of some samples."""
    crops, frames, bgs = [], [], []
    for i in tqdm(indices, desc=f"render {what}", disable=not progress):
        s = world.sample(split, int(i))
        crops.append(s.crop)
        frames.append(s.tactile)
        bgs.append(world.background_image(s.sensor))
    return {"crops": crops, "frames": frames, "backgrounds": bgs}


def _contact(data: dict) -> tuple[np.ndarray, np.ndarray]:
    """Contact scores of rendered frames without and with their backgrounds."""
    plain = np.array([contact_score(f) for f in data["frames"]])
    with_bg = np.array([contact_score(f, b) for f, b in zip(data["frames"], data["backgrounds"])])
    return plain, with_bg


def calibrate(encoders, cfg: TrustConfig = TrustConfig(), progress: bool = True
              ) -> TrustCalibration:
    """Fit and threshold the trust signals for `encoders`, and measure them on the test split.

    Returns:
        The calibration; its `meta` holds the data used and the measured rates.
    """
    world = World(WorldConfig(seed=cfg.seed)).warm()
    nc_world = World(WorldConfig(seed=cfg.seed).with_stress(no_contact=1.0)).warm()
    ref = _render(world, "train", range(cfg.n_reference), progress, "reference")
    val_idx = range(VALIDATION_START, VALIDATION_START + cfg.n_validation)
    val = _render(world, "train", val_idx, progress, "validation")
    test = _render(world, "test", range(TEST_SIZE), progress, "test")
    nc_test = _render(nc_world, "test", range(TEST_SIZE), progress, "test, no contact")
    enc = {name: (encoders.encode_image(d["crops"]), encoders.encode_tactile(d["frames"]))
           for name, d in (("ref", ref), ("val", val), ("test", test))}
    fa = cfg.false_alarm
    novelty = {}
    for m, col in (("visual", 0), ("tactile", 1)):
        model = Novelty.fit(enc["ref"][col], cfg.rank)
        novelty[m] = model.with_threshold(threshold_for(model.score(enc["val"][col]), fa))
    val_plain, val_bg = _contact(val)
    thr, thr_bg = threshold_for(val_plain, fa, above=False), threshold_for(val_bg, fa, False)
    test_plain, test_bg = _contact(test)
    nc_plain, nc_bg = _contact(nc_test)
    measured = {
        "visual_false_alarm_test": _rate(novelty["visual"].score(enc["test"][0])
                                         > novelty["visual"].threshold),
        "tactile_false_alarm_test": _rate(novelty["tactile"].score(enc["test"][1])
                                          > novelty["tactile"].threshold),
        "no_contact_false_alarm_test": _rate(test_plain < thr),
        "no_contact_false_alarm_test_bg": _rate(test_bg < thr_bg),
        "no_contact_detected_test": _rate(nc_plain < thr),
        "no_contact_detected_test_bg": _rate(nc_bg < thr_bg),
    }
    meta = {"world_seed": cfg.seed, "reference": f"train[0:{cfg.n_reference}]",
            "validation": f"train[{VALIDATION_START}:{VALIDATION_START + cfg.n_validation}]",
            "test": f"test[0:{TEST_SIZE}] (measured only)", "target_false_alarm": fa,
            "rank": cfg.rank, "measured": measured}
    log.info("trust calibration for %s: %s", encoders.name, measured)
    return TrustCalibration(encoders.name, novelty["visual"], novelty["tactile"], thr, thr_bg,
                            meta)


def _rate(flags: np.ndarray) -> float:
    return round(float(np.mean(flags)), 4)
