"""Taxim's optics (world/taxim_optics.py): the numpy port against the taxim package's own JAX
renderer, a frame without contact is the background, real presses are what they say, and the
world's pressing shapes (rigid materials keep a sphere, compliant ones flatten it)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from ratouch.errors import DataNotFoundError
from ratouch.world.config import WorldConfig
from ratouch.world.material import material
from ratouch.world.sampler import World
from ratouch.world.tactile import family_sensors, gel_surface, plan_tactile
from ratouch.world.taxim_optics import calibration_dir, optics, real_presses


def _ball(hw=(96, 128), radius_mm=4.0, press_mm=1.0, pixmm=0.0295 * 640 / 128):
    h, w = hw
    ys, xs = np.mgrid[0:h, 0:w]
    d2 = ((xs - w / 2) * pixmm) ** 2 + ((ys - h / 2) * pixmm) ** 2
    hm = np.where(d2 < radius_mm ** 2, radius_mm - np.sqrt(np.maximum(radius_mm ** 2 - d2, 0)),
                  radius_mm)
    return hm - hm.min() - press_mm


@pytest.mark.parametrize("name", ["gelsight", "gelsight_mini"])
def test_port_matches_the_taxim_packages_renderer(name):
    pytest.importorskip("jax")  # the test extra installs taxim's JAX backend
    import taxim

    sim = taxim.Taxim(calib_folder=calibration_dir(name), backend="jax")
    hm = _ball()
    theirs = np.asarray(sim.render(hm.astype(np.float32), with_shadow=False))
    ours = optics(name).render(hm)
    d = np.abs(theirs - ours) * 255
    # the same model; blur kernels and resizing differ in the last levels
    assert d.mean() < 2.0 and np.percentile(d, 99) < 10, (d.mean(), np.percentile(d, 99))
    # and the press shows: far more change inside the ball's disk than outside it
    change = np.abs(ours - optics(name).render(np.full(hm.shape, 1.0))).mean(2)
    inside = hm < 0
    assert change[inside].mean() > 5 * change[~inside].mean()


@pytest.mark.parametrize("name", ["gelsight", "gelsight_mini"])
def test_no_contact_changes_nothing(name):
    flat = np.full((96, 128), 0.5)  # above the gel everywhere
    assert np.abs(optics(name).change(flat)).max() < 1e-6


def test_real_presses_ship_with_their_backgrounds_and_touches():
    for name, n in (("gelsight", 48), ("gelsight_mini", 24)):
        d = real_presses(name)
        assert d["frames"].shape == (n, 480, 640, 3) and d["frames"].dtype == np.uint8
        assert d["background"].shape == (480, 640, 3)
        assert d["centres"].shape == (n, 2) and np.all(d["radii"] > 10)


def test_an_unknown_calibration_is_named():
    with pytest.raises(DataNotFoundError, match="digit"):
        calibration_dir("digit")


def test_rigid_materials_keep_a_sphere_and_compliant_ones_flatten_it():
    world = World(WorldConfig(seed=0))
    hw = world.cfg.tactile_hw
    unit = family_sensors("mini")[0]

    def plateau(name: str) -> float:
        p = plan_tactile(np.random.default_rng(3), world.cfg, material(name), sensor=unit)
        p = dataclasses.replace(p, shape="sphere", centre=(0.5, 0.5), force=1.0)
        _, dome = gel_surface(p, world.pyramid(material(name).feel.pattern), hw, dome=True)
        inside = dome[dome > 0.05 * dome.max()]
        return float(np.mean(inside > 0.9 * dome.max()))  # the share that is nearly flat

    rigid = [plateau(m) for m in ("glass", "polished_metal")]
    soft = [plateau(m) for m in ("sponge", "memory_foam")]
    assert max(rigid) + 0.1 < min(soft), (rigid, soft)


def _broad_press(hw=(96, 128), depth_mm=0.1):
    """A broad, shallow, flat press covering most of the frame (mm; < 0 into the gel)."""
    h, w = hw
    ys, xs = np.mgrid[0:h, 0:w]
    rho = np.hypot((xs - w / 2) / (0.45 * w), (ys - h / 2) / (0.45 * h))
    return -depth_mm * np.clip((1 - rho) / 0.1, 0, 1)


def test_a_shallow_broad_press_meets_a_domed_gel_only_when_measured_from_its_rest_surface():
    """The GelSight's gel is domed (its rest surface sags over a millimetre from apex to
    corner): a press 0.1 mm deep measured from the apex meets only the dome's top; measured
    from the rest surface (`on_gel`) it meets the gel wherever it covers it."""
    o = optics("gelsight")
    assert o.gel.min() < -1.0  # the dome
    height = _broad_press()
    rest = o._deform(np.full(height.shape, 1.0))
    covered = height < 0
    apex = (rest - o._deform(height)) > 1e-3
    on_gel = (rest - o._deform(height, on_gel=True)) > 1e-3
    assert apex[covered].mean() < 0.5 and on_gel[covered].mean() > 0.95
    # and a textured press (a weave's ridges) shows its texture over the patch, not only
    # at the dome's top
    xs = np.mgrid[0:height.shape[0], 0:height.shape[1]][1]
    woven = height * (1 + 0.5 * np.sin(xs / 1.5))
    seen = np.abs(o.change(woven, on_gel=True)).sum(2) > 2 / 255
    assert seen[covered].mean() > 0.8
    assert (np.abs(o.change(woven)).sum(2) > 2 / 255)[covered].mean() < 0.5


def test_on_a_flat_gel_the_rest_surface_is_the_apex():
    """The Mini's gel is flat: both conventions render the same change."""
    o = optics("gelsight_mini")
    height = _broad_press()
    np.testing.assert_array_equal(o.change(height), o.change(height, on_gel=True))
    flat = np.full((96, 128), 0.5)  # above the gel everywhere
    assert np.abs(o.change(flat, on_gel=True)).max() < 1e-6
