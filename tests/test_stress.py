"""Each stress knob does what it claims, measured on the generated output."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from ratouch.world.config import StressConfig, WorldConfig
from ratouch.world.material import material
from ratouch.world.sampler import World
from ratouch.world.silhouette import mask_bbox
from ratouch.world.tactile import plan_tactile, render_tactile, sensor_background

WILD = range(60, 400, 23)  # wild test samples


def _world(**knobs) -> World:
    return World(WorldConfig(seed=0, stress=StressConfig(**knobs)))


@pytest.mark.parametrize("scale", [0.1, 0.3, 0.6, 0.95])
def test_object_scale_sets_the_object_size_in_the_frame(scale):
    w = _world(object_scale=scale)
    for i in WILD:
        s = w.sample("test", i)
        x0, y0, x1, y1 = mask_bbox(s.object_mask)
        measured = max(x1 - x0, y1 - y0) / 128
        assert abs(measured - scale) <= 2.5 / 128 + 0.02, (i, measured)


def test_clutter_adds_distractor_pixels():
    none = [_world(clutter=0).sample("test", i).distractor_mask.mean() for i in WILD]
    many = [_world(clutter=8).sample("test", i).distractor_mask.mean() for i in WILD]
    assert max(none) == 0.0
    assert np.mean(many) > 0.05


def _gradient_energy(img: np.ndarray, region: np.ndarray) -> float:
    g = img.astype(float).mean(axis=2)
    gy, gx = np.gradient(g)
    return float(np.sqrt(gx ** 2 + gy ** 2)[region].mean())


def test_background_dominance_makes_the_background_louder():
    quiet, loud = [], []
    for i in WILD:
        a = _world(background_dominance=0.0, clutter=0).sample("test", i)
        b = _world(background_dominance=1.0, clutter=0).sample("test", i)
        quiet.append(_gradient_energy(a.visual, ~a.object_mask))
        loud.append(_gradient_energy(b.visual, ~b.object_mask))
    assert np.mean(loud) > 1.5 * np.mean(quiet)
    assert np.mean(np.array(loud) > np.array(quiet)) >= 0.8


def _high_freq(img: np.ndarray) -> float:
    g = img.astype(float).mean(axis=2)
    lap = 4 * g[1:-1, 1:-1] - g[:-2, 1:-1] - g[2:, 1:-1] - g[1:-1, :-2] - g[1:-1, 2:]
    return float(np.abs(lap).mean())


def test_tactile_noise_and_blur_change_high_frequency_content():
    idx = list(WILD)
    hf = {}
    for name, knobs in {"clean": dict(tactile_noise=0.0, tactile_blur=0.0),
                        "noisy": dict(tactile_noise=0.08, tactile_blur=0.0),
                        "blurred": dict(tactile_noise=0.0, tactile_blur=3.0)}.items():
        w = _world(**knobs)
        hf[name] = np.mean([_high_freq(w.sample("test", i).tactile) for i in idx])
    assert hf["noisy"] > 3 * hf["clean"]
    assert hf["blurred"] < 0.5 * hf["clean"]


def _orientation(img: np.ndarray) -> float:
    """Dominant gradient orientation (degrees, mod 180) of the contact patch: structure
    tensor summed over the colour channels (each light shades a different direction)."""
    h, w = img.shape[:2]
    sl = (slice(h // 2 - 10, h // 2 + 10), slice(w // 2 - 10, w // 2 + 10))
    jxx = jyy = jxy = 0.0
    for ch in range(3):
        c = img[..., ch].astype(float)
        c = c - gaussian_filter(c, 3)  # drop the contact dome's smooth shading, keep texture
        gy, gx = np.gradient(c)
        jxx += (gx[sl] ** 2).sum()
        jyy += (gy[sl] ** 2).sum()
        jxy += (gx[sl] * gy[sl]).sum()
    return float(np.degrees(0.5 * np.arctan2(2 * jxy, jxx - jyy)) % 180)


@pytest.mark.parametrize("angle", [30.0, 90.0])
def test_tactile_rotation_rotates_the_pressed_texture(angle):
    cfg0 = WorldConfig(stress=StressConfig(tactile_rotation=0.0, tactile_noise=0.0))
    cfg1 = WorldConfig(stress=StressConfig(tactile_rotation=angle, tactile_noise=0.0))
    w = World(cfg0)
    mat = material("corduroy")  # ribs: a strongly oriented texture
    errs = []
    for seed in range(6):
        p0 = plan_tactile(np.random.default_rng(seed), cfg0, mat)
        p1 = plan_tactile(np.random.default_rng(seed), cfg1, mat)
        p0 = p0.__class__(**{**p0.__dict__, "centre": (0.5, 0.5)})
        p1 = p1.__class__(**{**p1.__dict__, "centre": (0.5, 0.5)})
        bg = sensor_background(p0.sensor, cfg0.tactile_hw)
        o0 = _orientation(render_tactile(p0, w.pyramid, cfg0.tactile_hw, bg))
        o1 = _orientation(render_tactile(p1, w.pyramid, cfg0.tactile_hw, bg))
        d = (o0 - o1) % 180  # image y points down: counter-clockwise lowers the angle
        errs.append(min(abs(d - angle), abs(d - angle + 180), abs(d - angle - 180)))
    assert np.median(errs) < 12, errs


def _iou(a, b) -> float:
    ix = max(0, min(a[2], b[2]) - max(a[0], b[0]))
    iy = max(0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = ix * iy
    area = lambda r: (r[2] - r[0]) * (r[3] - r[1])  # noqa: E731
    return inter / (area(a) + area(b) - inter)


def test_box_offset_moves_the_reported_box_off_the_truth():
    same = [_world().sample("test", i) for i in WILD]
    assert all(s.box == s.box_true for s in same)
    shifted = [_world(box_offset=1.0).sample("test", i) for i in WILD]
    ious = [_iou(s.box, s.box_true) for s in shifted]
    assert np.mean(ious) < 0.35
    for s in shifted:  # the ground truth itself does not move, and boxes keep their size
        assert s.box_true == _world().sample("test", s.index).box_true
        assert s.box[2] - s.box[0] == s.box_true[2] - s.box_true[0]


def test_missing_modalities():
    v = _world(missing="visual").sample("test", 100)
    assert v.visual.std() == 0
    t = _world(missing="tactile", tactile_noise=0.0, tactile_blur=0.0)
    s = t.sample("test", 100)
    assert not s.contact
    assert np.abs(s.tactile.astype(int) - t.background_image(s.sensor)).max() <= 1
