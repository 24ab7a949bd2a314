"""Rendered sensor frames against real ones, in numbers (`ratouch eval sensors`).

For each sensor family, contact renders (read against their unit's background) beside the
real presses the project can see: Taxim's presses of a rigid ball on a real GelSight and
GelSight Mini (`world.taxim_optics.real_presses`), and for a family whose row names real
frames (`SensorFamily.reference`: the DIGIT's pressed reference frame against the tacto
no-contact frame, another unit, a rough comparison) those. Per set of
frames: the per-channel mean and spread of frame - background (levels of 255), how the
difference's energy spreads over spatial frequencies (share in three bands of cycles per
frame width, at a common 128-pixel longer side), and the contact area (share of the frame in
the largest region that differs, `eval.frames.contact_region`).

For looking and for the docs; nothing is tuned on the real frames.
"""

from __future__ import annotations

import numpy as np

from ratouch.eval.frames import contact_region
from ratouch.eval.photos import reference_dir
from ratouch.images import resize_array, to_rgb_array
from ratouch.world.config import WorldConfig
from ratouch.world.material import MATERIALS
from ratouch.world.sampler import World
from ratouch.world.sensors import canonical, family, family_names, family_sensors
from ratouch.world.tactile import plan_tactile, render_tactile
from ratouch.world.taxim_optics import real_presses

#: Spatial-frequency bands (cycles per frame width at 96 px wide): coarse, mid, fine.
BANDS = ((1, 4), (4, 12), (12, 48))


def frame_stats(frames: list[np.ndarray], backgrounds: list[np.ndarray]) -> dict:
    """The numbers of one set of frames, each against its background (uint8 RGB)."""
    means, spreads, bands, areas = [], [], [], []
    for f, b in zip(frames, backgrounds):
        f, b = canonical(f), canonical(b)
        d = f.astype(np.float32) - b.astype(np.float32)
        means.append(d.reshape(-1, 3).mean(0))
        spreads.append(d.reshape(-1, 3).std(0))
        areas.append(float(contact_region(f, b).mean()))
        small = resize_array(np.ascontiguousarray(np.abs(d).mean(2)), (96, 128))
        power = np.abs(np.fft.fftshift(np.fft.fft2(small - small.mean()))) ** 2
        h, w = power.shape
        fy, fx = np.meshgrid(np.arange(h) - h // 2, (np.arange(w) - w // 2) * h / w,
                             indexing="ij")
        radius = np.hypot(fy, fx) * w / h  # cycles per frame width
        total = power.sum() + 1e-12
        bands.append([float(power[(radius >= lo) & (radius < hi)].sum() / total)
                      for lo, hi in BANDS])
    return {"n": len(frames),
            "mean": [round(float(v), 2) for v in np.mean(means, 0)],
            "spread": [round(float(v), 2) for v in np.mean(spreads, 0)],
            "bands": [round(float(v), 3) for v in np.mean(bands, 0)],
            "contact_area": round(float(np.mean(areas)), 3)}


def rendered(world: World, name: str, n: int, seed: int = 0
             ) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """`n` contact frames of family `name` (materials in turn, units in turn) and their
    backgrounds."""
    units = list(family_sensors(name))
    frames, bgs = [], []
    mats = list(MATERIALS)
    for i in range(n):
        p = plan_tactile(np.random.default_rng([seed, i]), world.cfg, mats[i % len(mats)],
                         sensor=units[i % len(units)])
        frames.append(render_tactile(p, world.pyramid, world.cfg.tactile_hw,
                                     world.sensor_background(p.sensor)))
        bgs.append(world.background_image(p.sensor))
    return frames, bgs


def real(name: str) -> tuple[list[np.ndarray], list[np.ndarray], str] | None:
    """The real presses of family `name` with their backgrounds and where they come from: a
    Taxim row's calibration presses, else the row's own real frames (None: the row names
    none, or their files are missing)."""
    row = family(name)
    if row.calibration is not None:
        d = real_presses(row.calibration)
        return (list(d["frames"]), [d["background"]] * len(d["frames"]),
                f"Taxim's {len(d['frames'])} real presses of a rigid ball ({row.calibration})")
    if row.reference is None:
        return None
    pressed, blank = (reference_dir() / f for f in (row.reference.pressed, row.reference.background))
    if not (pressed.is_file() and blank.is_file()):
        return None
    p, b = to_rgb_array(pressed, "tactile image"), to_rgb_array(blank, "background")
    return [p], [b], row.reference.note


def compare_sensors(n: int = 60, seed: int = 0) -> dict:
    """Per family: the renders' numbers and the real frames' (where there are any)."""
    world = World(WorldConfig(seed=seed)).warm()
    out = {}
    for name in family_names():
        frames, bgs = rendered(world, name, n, seed)
        row = {"renders": frame_stats(frames, bgs)}
        found = real(name)
        if found is not None:
            row["real"] = {**frame_stats(found[0], found[1]), "source": found[2]}
        out[name] = row
    return out


def format_sensors(result: dict) -> str:
    """A markdown table of `compare_sensors`."""
    lo = [f"{a}-{b}" for a, b in BANDS]
    lines = ["| family | frames | n | mean of frame - bg (R, G, B) | spread (R, G, B) | energy "
             f"share at {', '.join(lo)} cycles/width | contact area |",
             "|---|---|---|---|---|---|---|"]
    for name, row in result.items():
        for kind in ("renders", "real"):
            s = row.get(kind)
            if s is None:
                continue
            what = "renders" if kind == "renders" else f"real: {s['source']}"
            lines.append(f"| {name} | {what} | {s['n']} | {s['mean']} | {s['spread']} | "
                         f"{s['bands']} | {s['contact_area']} |")
    return "\n".join(lines)
