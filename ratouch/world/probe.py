"""The world's own evidence that it needs both senses.

A simple classifier (logistic regression on colour, gradient and frequency statistics)
predicts the material of held-out samples from the visual crop in the contact box only, the
tactile frame only (minus the sensor's background, as TVL's loader subtracts it), and both.
Designed ambiguity should show: vision confuses look-alike groups, touch the feel-alike ones.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from PIL import Image
from sklearn.linear_model import LogisticRegression
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import StandardScaler
from tqdm import tqdm

from ratouch.errors import ConfigError
from ratouch.images import resize_array
from ratouch.processes import worker_pool
from ratouch.world.config import WorldConfig
from ratouch.world.dataset import world_for
from ratouch.world.material import MATERIAL_INDEX, MATERIALS, groups


@dataclass(frozen=True)
class ProbeConfig:
    n_train: int = 2400
    n_test: int = 800
    workers: int = 2
    C: float = 0.5  # inverse regularisation of the logistic regression

    def __post_init__(self) -> None:
        if self.n_train < len(MATERIALS):
            raise ConfigError(f"n_train={self.n_train} must be >= {len(MATERIALS)} "
                              f"(one per material)")
        if self.n_test < 1:
            raise ConfigError(f"n_test={self.n_test} must be >= 1")
        if self.workers < 1:
            raise ConfigError(f"workers={self.workers} must be >= 1")
        if self.C <= 0:
            raise ConfigError(f"C={self.C} must be > 0")


def _radial_bands(gray: np.ndarray, n_bands: int = 8) -> np.ndarray:
    """Log power of the image spectrum in `n_bands` radial frequency bands."""
    f = np.abs(np.fft.fftshift(np.fft.fft2(gray - gray.mean()))) ** 2
    h, w = gray.shape
    yy, xx = np.mgrid[0:h, 0:w]
    r = np.sqrt((yy - h / 2) ** 2 + (xx - w / 2) ** 2) / (min(h, w) / 2)
    edges = np.linspace(0.02, 1.0, n_bands + 1)
    return np.log1p(np.array([f[(r >= a) & (r < b)].mean() for a, b in zip(edges, edges[1:])]))


def _gradient_stats(gray: np.ndarray, n_bins: int = 8) -> np.ndarray:
    """Mean / std of gradient magnitude and a magnitude-weighted orientation histogram,
    rotated to its dominant bin (so texture direction does not matter, anisotropy does)."""
    gy, gx = np.gradient(gray)
    mag = np.sqrt(gx ** 2 + gy ** 2)
    ang = np.mod(np.arctan2(gy, gx), np.pi)
    hist, _ = np.histogram(ang, bins=n_bins, range=(0, np.pi), weights=mag)
    hist = hist / (hist.sum() + 1e-8)
    hist = np.roll(hist, -int(np.argmax(hist)))
    lap = np.abs(gray[1:-1, 1:-1] * 4 - gray[:-2, 1:-1] - gray[2:, 1:-1] - gray[1:-1, :-2]
                 - gray[1:-1, 2:])
    return np.concatenate([[mag.mean(), mag.std(), np.percentile(mag, 90), lap.mean()], hist])


def visual_features(image: np.ndarray, box) -> np.ndarray:
    """Features of the visual crop inside the contact box."""
    x0, y0, x1, y1 = box
    crop = resize_array(image[y0:y1, x0:x1], 48)
    rgb = crop.astype(np.float32) / 255
    gray = rgb.mean(axis=2)
    mx, mn = rgb.max(axis=2), rgb.min(axis=2)
    sat = (mx - mn) / (mx + 1e-3)
    hsv = np.asarray(Image.fromarray(crop).convert("HSV"), np.float32) / 255
    hue_hist, _ = np.histogram(hsv[..., 0], bins=12, range=(0, 1), weights=sat + 1e-3)
    hue_hist = hue_hist / hue_hist.sum()
    bright = (gray > np.percentile(gray, 50) + 0.25).mean()  # specular highlight share
    colour = np.concatenate([rgb.mean((0, 1)), rgb.std((0, 1)),
                             np.percentile(gray, [5, 25, 50, 75, 95]),
                             [sat.mean(), sat.std(), bright], hue_hist])
    return np.concatenate([colour, _gradient_stats(gray), _radial_bands(gray, 10)])


def tactile_features(tactile: np.ndarray, background: np.ndarray) -> np.ndarray:
    """Features of the tactile frame after subtracting the sensor's background."""
    diff = tactile.astype(np.float32) / 255 - background.astype(np.float32) / 255
    energy = np.abs(diff).sum(axis=2)
    contact = energy > 0.08
    area = contact.mean()
    gray = diff.mean(axis=2)
    ys, xs = np.nonzero(contact)
    if len(ys) > 16:  # the texture inside the contact patch
        cy, cx = int(ys.mean()), int(xs.mean())
        r = 12
        patch = diff[max(0, cy - r):cy + r, max(0, cx - r):cx + r]
    else:
        patch = diff[:24, :24]
    pg = patch.mean(axis=2)
    return np.concatenate([
        [area, energy.mean(), energy.std(), np.percentile(energy, 95)],
        diff.std((0, 1)), patch.std((0, 1)),
        _gradient_stats(pg), _radial_bands(pg, 6), _radial_bands(gray, 6),
    ])


def _features_chunk(args: tuple[WorldConfig, str, list[int]]):

    cfg, split, indices = args
    world = world_for(cfg)
    out = []
    for i in indices:
        s = world.sample(split, i)
        bg = world.background_image(s.sensor)
        out.append((visual_features(s.visual, s.box), tactile_features(s.tactile, bg),
                    MATERIAL_INDEX[s.material]))
    return out


def _collect(cfg: WorldConfig, start: int, n: int, workers: int, progress: bool):

    idx = list(range(start, start + n))
    chunks = [(cfg, "probe", idx[k:k + 100]) for k in range(0, n, 100)]
    rows = []
    bar = tqdm(total=n, desc="probe samples", disable=not progress)
    if workers == 1:
        for c in chunks:
            rows.extend(_features_chunk(c))
            bar.update(len(c[2]))
    else:
        world_for(cfg).warm()
        with worker_pool(workers) as pool:
            for part in pool.map(_features_chunk, chunks):
                rows.extend(part)
                bar.update(len(part))
    bar.close()
    v = np.stack([r[0] for r in rows])
    t = np.stack([r[1] for r in rows])
    y = np.array([r[2] for r in rows])
    return v, t, y


def _within_group_confusion(y: np.ndarray, pred: np.ndarray, kind: str) -> dict[str, float]:
    """Per group: share of the group's samples predicted as another member of the group."""
    out = {}
    for g, names in groups(kind).items():
        ids = [MATERIAL_INDEX[n] for n in names]
        sel = np.isin(y, ids)
        if sel.any():
            out[g] = float(np.mean(np.isin(pred[sel], ids) & (pred[sel] != y[sel])))
    return out


def run_probe(world_cfg: WorldConfig, cfg: ProbeConfig, progress: bool = True) -> dict:
    """Fit the three probes on `n_train` samples, report on `n_test` held-out ones.

    Returns:
        {"visual": acc, "tactile": acc, "both": acc, "chance": ..., "n_train": ...,
         "confusion": {"look": {mode: {group: rate}}, "feel": {...}}}.
    """
    vtr, ttr, ytr = _collect(world_cfg, 0, cfg.n_train, cfg.workers, progress)
    vte, tte, yte = _collect(world_cfg, cfg.n_train, cfg.n_test, cfg.workers, progress)
    feats = {
        "visual": (vtr, vte), "tactile": (ttr, tte),
        "both": (np.hstack([vtr, ttr]), np.hstack([vte, tte])),
    }
    result: dict = {"n_train": cfg.n_train, "n_test": cfg.n_test, "n_materials": len(MATERIALS),
                    "chance": 1.0 / len(MATERIALS)}
    conf: dict = {"look": {}, "feel": {}}
    for mode, (xtr, xte) in feats.items():
        clf = make_pipeline(StandardScaler(), LogisticRegression(C=cfg.C, max_iter=3000))
        clf.fit(xtr, ytr)
        pred = clf.predict(xte)
        result[mode] = float(np.mean(pred == yte))
        conf["look"][mode] = _within_group_confusion(yte, pred, "look")
        conf["feel"][mode] = _within_group_confusion(yte, pred, "feel")
    result["confusion"] = conf
    return result


def format_probe(result: dict) -> str:
    """Human-readable probe report."""
    lines = [f"material probe: {result['n_materials']} materials, {result['n_train']} train / "
             f"{result['n_test']} held-out samples, chance {result['chance']:.3f}",
             f"  visual only : {result['visual']:.3f}",
             f"  tactile only: {result['tactile']:.3f}",
             f"  both        : {result['both']:.3f}",
             "within-group confusion (share of a group's samples taken for another member):"]
    for kind, title in (("look", "look-alike groups"), ("feel", "feel-alike groups")):
        lines.append(f"  {title:<18} {'visual':>8} {'tactile':>8} {'both':>8}")
        for g in result["confusion"][kind]["visual"]:
            vals = [result["confusion"][kind][m][g] for m in ("visual", "tactile", "both")]
            lines.append(f"    {g:<16} " + " ".join(f"{v:8.2f}" for v in vals))
    return "\n".join(lines)
