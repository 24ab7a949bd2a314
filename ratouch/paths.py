"""Where things live on disk: the checkout, the shipped weights, the cache and outside data.

One module owns these folders so that no other module works them out from its own `__file__`
(which moves when a module moves). Every folder can be overridden by an environment variable:

* ``$RATOUCH_ASSETS`` — the weights and calibrations a query loads (default the shipped
  ``assets/``; e.g. a copy to try damaged files on);
* ``$RATOUCH_CACHE`` — cached corpora, training data, experiment and failure results, the
  sensors' measured drift
  (default ``~/.cache/ratouch``);
* ``$RATOUCH_TVL_JUDGE_DIR`` — the published TVL judge files (default
  ``../shared/data/tvl_judge`` beside the checkout).
"""

from __future__ import annotations

import os
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent
REPO = PACKAGE.parent                      # the checkout (app/, docs/, assets/ sit here)
ASSETS = REPO / "assets"                   # shipped weights
CONFIGS = PACKAGE / "configs"              # named encoder configs, the judge's calibration
DOCS = REPO / "docs"
APP_FILE = REPO / "app" / "app.py"
TVL_JUDGE_ENV = "RATOUCH_TVL_JUDGE_DIR"


def cache_dir() -> Path:
    """Where cached corpora and training data live: $RATOUCH_CACHE, else ~/.cache/ratouch."""
    return Path(os.environ.get("RATOUCH_CACHE", Path.home() / ".cache" / "ratouch"))


def assets_dir() -> Path:
    """Where the weights and calibrations are read from and trained into: $RATOUCH_ASSETS,
    else the shipped `assets/`."""
    return Path(os.environ.get("RATOUCH_ASSETS", ASSETS))


def encoder_weights(encoder: str) -> Path:
    """Shipped weights of a default-backend encoder."""
    return assets_dir() / "encoders" / encoder


def retriever_weights(encoder: str) -> Path:
    """The shipped Tactile-Guided Retriever trained for an encoder."""
    return assets_dir() / "retriever" / encoder


def generator_weights(encoder: str, kind: str, lm: str | None = None) -> Path:
    """A shipped generator (`kind` "ra" or "baseline") for an encoder; on the pretrained
    language model `lm` ("smollm2-135m") when given, else on the small decoder."""
    return assets_dir() / "generator" / encoder / (f"{lm}/{kind}" if lm else kind)


def trust_calibration(encoder: str) -> Path:
    """The shipped trust calibration (novelty and no-contact thresholds) of an encoder."""
    return assets_dir() / "trust" / f"{encoder}.json"


def touch_gate(encoder: str) -> Path:
    """The shipped touch gate of an encoder set (`ratouch.model.gate`)."""
    return assets_dir() / "gate" / f"{encoder}.json"


def press_map(encoder: str) -> Path:
    """The shipped press map of an encoder set (`ratouch.model.press_map`)."""
    return assets_dir() / "press_map" / f"{encoder}.npz"


def geometry_calibration() -> Path:
    """The shipped geometry lookups (colour change to surface gradient, per sensor family)."""
    return ASSETS / "geometry" / "lookups.json"


def cascade_calibration(encoders: str = "default-tiny+default-s") -> Path:
    """The shipped cascade calibration (stages, confidence measure, thresholds)."""
    return assets_dir() / "cascade" / f"{encoders}.json"


def tvl_judge_dir() -> Path:
    """The published TVL result files with GPT-4 scores (read, never copied into the repo)."""
    env = os.environ.get(TVL_JUDGE_ENV)
    return Path(env) if env else REPO.parent / "shared" / "data" / "tvl_judge"


def converted_lm_dir(name: str, fingerprint: str) -> Path:
    """The cached converted copy of a pretrained language model (`model/pretrained_lm.py`),
    named by the model and the sha256 fingerprint of the file it was converted from."""
    return cache_dir() / "lm" / f"{name}-{fingerprint[:16]}"
