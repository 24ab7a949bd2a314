"""The scarce-touch regime: which world pairs a paired training split holds.

Real paired touch data is long-tailed: a few materials and objects are pressed thousands of
times, many are pressed a handful of times, while a web-scale image corpus (ImageNet) covers
every class. `ScarceRegime` reproduces that on the world without changing any render: it
*selects* training pairs from the world's train split.

* A seeded draw of `n_scarce` materials (the world seed fixes it: the same materials are rare in
  every run on one world, as real rare materials are) keeps at most `tail_pairs` pairs each.
* Every other material keeps the world's own long-tailed frequencies (object classes have
  weighted materials, so oak or glossy plastic are common and corduroy is rare).
* `draw` picks *which* pairs of the scarce materials are kept (and seeds nothing else): runs
  with different draws see different few examples of the same rare materials.

`regime="full"` keeps the train split as it is (the world before the scarce regime); the test
split and the corpus are never filtered. `premise_indices` selects held-out renders of a
material group (seen or scarce) from the world's "probe" split, which no model trains on.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from ratouch.errors import ConfigError
from ratouch.world.config import WorldConfig
from ratouch.world.dataset import world_for
from ratouch.world.material import MATERIALS

REGIMES = ("scarce", "full")
#: First probe-split index of the premise groups' renders: beyond `ratouch world probe`'s.
PREMISE_START = 200_000


@dataclass(frozen=True)
class ScarceRegime:
    """Which pairs of the world's train split a paired training set holds.

    Attributes:
        regime: "scarce" (the default) or "full" (every pair, the world's natural frequencies).
        seed: the world's seed; it fixes which materials are scarce.
        draw: which few pairs of each scarce material are kept (0 for the shipped weights).
        n_scarce: how many materials are scarce.
        tail_pairs: the most pairs a scarce material keeps.
    """

    regime: str = "scarce"
    seed: int = 0
    draw: int = 0
    n_scarce: int = 14
    tail_pairs: int = 8

    def __post_init__(self) -> None:
        if self.regime not in REGIMES:
            raise ConfigError(f"regime={self.regime!r} must be one of {REGIMES}")
        for name in ("seed", "draw", "tail_pairs"):
            if getattr(self, name) < 0:
                raise ConfigError(f"{name}={getattr(self, name)} must be >= 0")
        if not 1 <= self.n_scarce < len(MATERIALS):
            raise ConfigError(f"n_scarce={self.n_scarce} must lie in [1, {len(MATERIALS)})")

    @property
    def tag(self) -> str:
        """A short name for cache keys."""
        if self.regime == "full":
            return "full"
        return f"scarce{self.n_scarce}x{self.tail_pairs}-d{self.draw}"

    def scarce_materials(self) -> tuple[str, ...]:
        """The materials this regime keeps few pairs of (empty for "full"), sorted."""
        if self.regime == "full":
            return ()
        rng = np.random.default_rng([self.seed, 7_301])
        pick = rng.choice(len(MATERIALS), size=self.n_scarce, replace=False)
        return tuple(sorted(MATERIALS[i].name for i in pick))

    def train_indices(self, n_pairs: int) -> list[int]:
        """The world train-split indices of the first `n_pairs` pairs this regime keeps."""
        if n_pairs < 1:
            raise ConfigError(f"n_pairs={n_pairs} must be >= 1")
        return list(_train_indices(self, n_pairs))


@lru_cache(maxsize=8)
def _train_indices(regime: ScarceRegime, n_pairs: int) -> tuple[int, ...]:
    if regime.regime == "full":
        return tuple(range(n_pairs))

    world = world_for(WorldConfig(seed=regime.seed))
    scarce = set(regime.scarce_materials())
    # Each scarce pair gets a key from the draw; a scarce material keeps the pairs with the
    # `tail_pairs` smallest keys among its first candidates, so a draw picks which few survive.
    rng = np.random.default_rng([regime.seed, 7_302, regime.draw])
    kept: list[int] = []
    candidates: dict[str, list[tuple[float, int]]] = {m: [] for m in scarce}
    i = 0
    while len(kept) < n_pairs:
        name = world.plan("train", i)[2].name
        if name in scarce:
            candidates[name].append((float(rng.random()), i))
        else:
            kept.append(i)
        i += 1
    # the scarce pairs come from the same stretch of indices as the head's
    tail = sorted(idx for c in candidates.values() for _, idx in sorted(c)[:regime.tail_pairs])
    tail = tail[:n_pairs]
    out = sorted(kept[:n_pairs - len(tail)] + tail)
    return tuple(out)


def premise_indices(group: str, n: int, regime: ScarceRegime) -> list[int]:
    """Probe-split indices of `n` held-out renders whose material is scarce ("scarce") or not
    ("seen") under `regime`. The probe split draws materials uniformly, then an object that
    has the material, so both groups are wild scenes balanced over their materials."""
    if group not in ("seen", "scarce"):
        raise ConfigError(f"group={group!r} must be 'seen' or 'scarce'")
    if regime.regime == "full":
        raise ConfigError("the premise groups need a scarce regime")

    world = world_for(WorldConfig(seed=regime.seed))
    scarce = set(regime.scarce_materials())
    out: list[int] = []
    i = PREMISE_START
    while len(out) < n:
        if (world.plan("probe", i)[2].name in scarce) == (group == "scarce"):
            out.append(i)
        i += 1
    return out

