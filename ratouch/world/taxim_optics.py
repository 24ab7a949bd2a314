"""Taxim's optical model of a vision-based tactile sensor, in numpy, on Taxim's calibrations.

Taxim (Si and Yuan, "Taxim: An Example-based Simulation Model for GelSight Tactile Sensors",
RA-L 2022) renders a pressed gel from its surface gradients: the gel's deformation under an
object is approximated by a pyramid of Gaussian blurs that keep the contact region fixed;
each pixel's gradient (magnitude, direction) selects, from a table calibrated on real presses
of a ball, a quadratic polynomial in the pixel's position that gives the colour change; the
sensor's real no-contact frame is added. The calibrations (`polycalib.npz`, `gelmap.npy`,
`params.json`, `dataPack.npz`'s no-contact frame `f0`) of a **GelSight** and a **GelSight
Mini** ship in the MIT-licensed `taxim` package on PyPI (Tim Schneider's GPU implementation);
this module reads them from that package's folder and re-implements the shadow-free render
from the paper and that package's description of it, in numpy (no JAX: the world renders in
forked workers, where JAX must not run). `tests/test_taxim_optics.py` checks it against the
package's own JAX renderer where that is installed.

One deliberate difference: Taxim's polynomial at zero gradient is not zero (on the Mini it
adds 11-22 of 255 per channel everywhere), so :meth:`TaximOptics.change` is the colour change
a press makes against the same gel without contact; a frame without contact is then exactly
the sensor's background, as on the real sensor.
"""

from __future__ import annotations

import importlib.util
import json
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
from scipy.ndimage import gaussian_filter

from ratouch.errors import DataNotFoundError
from ratouch.images import resize_array

#: The calibrations the `taxim` package ships (folder names under `taxim/calib/`).
CALIBRATIONS = ("gelsight", "gelsight_mini")


def calibration_dir(name: str) -> Path:
    """The folder of one of Taxim's calibrations, found without importing the package.

    Raises:
        DataNotFoundError: the `taxim` package is not installed or lacks the calibration.
    """
    spec = importlib.util.find_spec("taxim")
    if spec is None or not spec.submodule_search_locations:
        raise DataNotFoundError(
            "the `taxim` package (Taxim's real sensor calibrations) is not installed: "
            "pip install taxim")
    folder = Path(list(spec.submodule_search_locations)[0]) / "calib" / name
    if not (folder / "polycalib.npz").is_file():
        raise DataNotFoundError(f"no Taxim calibration {name!r} at {folder}; "
                                f"known: {', '.join(CALIBRATIONS)}")
    return folder


def _blur(img: np.ndarray, sigma_xy: tuple[float, float]) -> np.ndarray:
    """Gaussian blur with sigma (x, y) in pixels, reflected at the edges."""
    sx, sy = sigma_xy
    sig = (sy, sx) + ((0,) if img.ndim == 3 else ())
    return gaussian_filter(img, sigma=sig, mode="reflect", truncate=4.0)


def _rel(rel, hw: tuple[int, int]):
    """Taxim's `_rel` parameters are (width-relative, height-relative) pairs (or pairs of
    tuples): in pixels at frame size `hw` = (h, w)."""
    w_rel, h_rel = rel
    if isinstance(w_rel, (list, tuple)):
        return [(a * hw[1], b * hw[0]) for a, b in zip(w_rel, h_rel)]
    return (w_rel * hw[1], h_rel * hw[0])


@dataclass(frozen=True)
class TaximOptics:
    """One calibrated sensor (full resolution H x W, landscape) and its render at any size.

    Attributes:
        name: the calibration's name.
        poly: (bins, bins, 6, 3) polynomial coefficients by gradient (magnitude, direction), RGB.
        gel: (H, W) the undeformed gel's height, mm, at most 0.
        background: (H, W, 3) float [0, 1] RGB: the real no-contact frame as Taxim uses it.
        params: the calibration's simulator parameters (`params.json`, "simulator").
        pixmm: millimetres per pixel at full resolution.
    """

    name: str
    poly: np.ndarray
    gel: np.ndarray
    background: np.ndarray
    params: dict
    pixmm: float

    @property
    def hw(self) -> tuple[int, int]:
        return self.gel.shape[0], self.gel.shape[1]

    def background_at(self, hw: tuple[int, int]) -> np.ndarray:
        """The no-contact frame at size `hw` = (h, w), float [0, 1]."""
        return _resize_float(self.background, hw)

    def _deform(self, height: np.ndarray, on_gel: bool = False) -> np.ndarray:
        """The gel's surface (mm) under an object at `height` (mm; < 0 presses into the gel):
        the contact region keeps the object's shape, the gel around it relaxes (a pyramid of
        blurs that re-imposes the contact after each). `height` is measured from the gel's
        apex, or with `on_gel` from the gel's rest surface (the object follows a domed gel)."""
        hw = height.shape
        gel = _resize_float(self.gel, hw)
        press = -float(height.min())
        contact = height < 0
        joined = np.minimum(gel + height if on_gel else height, gel)
        mask = (joined - gel < -press * self.params["contact_scale"]) & contact
        out = joined
        for sigma in _rel(self.params["deform_pyramid_sigma_rel"], hw):
            out = np.where(mask, joined, _blur(out, sigma))
        return _blur(out, _rel(self.params["deform_final_sigma_rel"], hw))

    def _shade(self, surface: np.ndarray) -> np.ndarray:
        """Taxim's colour (before the background) of a gel surface (mm), (h, w, 3)."""
        h, w = surface.shape
        H, W = self.hw
        z = -surface / self.pixmm  # full-resolution pixel units, towards the camera
        dzdx = np.zeros_like(z)
        dzdy = np.zeros_like(z)
        # central differences; a step at this size is H / h full-resolution pixels
        dzdx[1:-1, 1:-1] = (z[2:, 1:-1] - z[:-2, 1:-1]) / 2 * h / H
        dzdy[1:-1, 1:-1] = (z[1:-1, 2:] - z[1:-1, :-2]) / 2 * w / W
        for a in (dzdx, dzdy):  # edge pixels take their neighbour's gradient
            a[0], a[-1] = a[1], a[-2]
            a[:, 0], a[:, -1] = a[:, 1], a[:, -2]
        tan = np.sqrt(dzdx ** 2 + dzdy ** 2)
        mag = np.arctan(tan)
        safe = np.where(tan > 0, tan, 1.0)
        direction = np.where(tan > 0, np.arctan2(dzdx / safe, dzdy / safe), 0.0)
        bins = self.poly.shape[0]
        i_mag = np.clip(np.floor(mag / (0.5 * np.pi / (bins - 1))).astype(np.int64), 0, bins - 1)
        i_dir = np.clip(np.floor((direction + np.pi) / (2 * np.pi / (bins - 1))).astype(np.int64),
                        0, bins - 1)
        coef = self.poly[i_mag, i_dir]  # (h, w, 6, 3)
        yy, xx = np.meshgrid(np.linspace(0, H, h, endpoint=False),
                             np.linspace(0, W, w, endpoint=False), indexing="ij")
        feats = np.stack([xx * xx, yy * yy, xx * yy, xx, yy, np.ones_like(xx)], -1)  # (h, w, 6)
        return np.einsum("hwk,hwkc->hwc", feats, coef)

    def change(self, height: np.ndarray, on_gel: bool = False) -> np.ndarray:
        """The colour change (float, (h, w, 3), RGB in [0, 1] units) that an object at
        `height` (mm, (h, w), landscape; < 0 presses into the gel) makes against the same gel
        without contact. `height` is measured from the gel's apex (Taxim's convention: a
        shallow press meets only the top of a domed gel), or with `on_gel` from the gel's
        rest surface (a press that meets the gel wherever it is below 0)."""
        height = np.asarray(height, np.float64)
        return (self._shade(self._deform(height, on_gel))
                - _resting(self.name, height.shape)).astype(np.float32)

    def render(self, height: np.ndarray) -> np.ndarray:
        """Taxim's frame (float [0, 1], RGB) of an object at `height`, as the `taxim`
        package renders it without shadows (its offset at zero gradient included)."""
        height = np.asarray(height, np.float64)
        out = self._shade(self._deform(height)) + self.background_at(height.shape)
        return np.clip(out, 0, 1).astype(np.float32)


@lru_cache(maxsize=8)
def _resting(name: str, hw: tuple[int, int]) -> np.ndarray:
    """Taxim's colour of the gel without contact at size `hw` (cached, read-only)."""
    o = optics(name)
    out = o._shade(o._deform(np.full(hw, 1.0)))  # above the gel everywhere
    out.setflags(write=False)
    return out


def _resize_float(a: np.ndarray, hw: tuple[int, int]) -> np.ndarray:
    if a.shape[:2] == tuple(hw):
        return a
    size = (int(hw[1]), int(hw[0]))
    if a.ndim == 2:
        return resize_array(a.astype(np.float32), size)
    return np.stack([resize_array(np.ascontiguousarray(a[..., c], np.float32), size)
                     for c in range(a.shape[2])], -1)


@lru_cache(maxsize=len(CALIBRATIONS))
def optics(name: str) -> TaximOptics:
    """One of Taxim's calibrated sensors (cached; read-only arrays).

    Raises:
        DataNotFoundError: the `taxim` package or the calibration is missing.
    """
    folder = calibration_dir(name)
    params = json.loads((folder / "params.json").read_text(encoding="utf-8"))
    sim, sensor = params["simulator"], params["sensor"]
    with np.load(folder / "polycalib.npz") as d:
        # the file's channel names are swapped: grad_b holds red
        poly = np.stack([d["grad_b"], d["grad_g"], d["grad_r"]], -1).astype(np.float64) / 255
    pixmm = float(sensor["pixmm"])
    gel = np.load(folder / "gelmap.npy").astype(np.float64)
    gel = _blur(gel, _rel(sim["deform_final_sigma_rel"], gel.shape)) * pixmm
    gel = gel - gel.max()
    with np.load(folder / "dataPack.npz", allow_pickle=False) as d:
        f0 = d["f0"][..., ::-1].astype(np.float64) / 255  # stored BGR
    smooth = _blur(f0, _rel(sim["initial_frame_sigma_rel"], f0.shape[:2]))
    mix = float(sim["frame_mixing_percentage"])
    background = (mix * smooth + (1 - mix) * f0).astype(np.float32)
    for a in (poly, gel, background):
        a.setflags(write=False)
    return TaximOptics(name, poly, gel, background, sim, pixmm)


def real_presses(name: str) -> dict:
    """The real frames a Taxim calibration was made from: `frames` (N, H, W, 3) uint8 RGB
    presses of a rigid ball, `background` (H, W, 3) uint8 RGB, `centres` (N, 2) pixel (x, y)
    and `radii` (N,) pixels of the touches (a visible real test set; nothing is tuned on it)."""
    folder = calibration_dir(name)
    with np.load(folder / "dataPack.npz", allow_pickle=False) as d:
        return {"frames": np.ascontiguousarray(d["imgs"][..., ::-1]),
                "background": np.ascontiguousarray(d["f0"][..., ::-1]),
                "centres": np.asarray(d["touch_center"], np.float64),
                "radii": np.asarray(d["touch_radius"], np.float64)}
