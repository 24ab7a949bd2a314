"""Touch read as geometry: a calibrated sensor's colour change becomes surface gradients, and
the gradients a height map.

This is how GelSight's own reconstruction works: a lookup from a pixel's colour change (and
its position on the gel, whose lighting is not uniform) to the surface gradient there, fitted
on presses of a ball of known size, then Poisson integration of the gradient field to a height
map. Read this way a press is depth in millimetres, independent of the gel's colours and its
lighting, and three measures follow from the height map:

* **depth**: how far the surface is pushed in (the 99.5th percentile of the height above its
  median);
* **spread**: the share of the gel pushed in by more than a third of that depth (a compliant
  object wraps the gel: a wide, shallow patch; a rigid one a small, deep one);
* **relief**: the RMS of the height map's detail (the height minus its blur at
  :data:`RELIEF_SIGMA`), the surface's texture.

A lookup (:class:`GradientLookup`) is a small multilayer perceptron from (colour change RGB,
x, y) to (dz/dx, dz/dy), evaluated in numpy; `ratouch train geometry`
(`ratouch.train.geometry`) fits one per sensor family — on Taxim's real ball presses for the
GelSight and the GelSight Mini, on the world shader's renders of ball presses for the DIGIT.
The file is `ratouch.paths.geometry_calibration()`.

Before the lookup, the global change between a background and a later frame (a gain and an
offset per channel, which lighting drift makes) is removed by a robust fit over the frame,
so that what is read is structured local change. **Contact against a background** is decided
on that structured change (:func:`band_stats`: band-passed edges and texture), against
each family's floors set on blank pairs (a background and a later no-contact frame, with the
drift Taxim's real pairs show): shallow, broad presses of fabrics and foams, which change a
GelSight Mini's pixels by a few levels, stand above those floors where a threshold on the
whole change does not.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ratouch.errors import DataError, DataNotFoundError
from ratouch.files import write_atomic
from ratouch.images import check_background_size, gaussian_blur, resize_array

FORMAT = "ratouch-geometry-1"
#: Working size (width, height) of a landscape sensor's frame (a portrait one: transposed).
WORK_LANDSCAPE = (160, 120)
#: Sigma (working pixels) of the light blur before the lookup (sensor noise).
CHANGE_SIGMA = 1.0
#: Sigma (working pixels) of the blur whose residual is the relief (texture).
RELIEF_SIGMA = 4.0
#: pixels the lookup's perceptron reads at a time (32 activations each: 240 kB in float64)
_COLUMNS = 960
#: Scale of the colour change at the lookup's input ([0, 1] units -> about unit spread).
CHANGE_SCALE = 10.0


# ----------------------------------------------------------------------------- the lookup

@dataclass(frozen=True)
class GradientLookup:
    """One sensor family's colour-change-to-gradient lookup.

    Attributes:
        family: the sensor family (a key of `ratouch.world.sensors.SENSOR_FAMILIES`).
        weights, biases: the perceptron's layers (ReLU between them, linear output);
            input (dR, dG, dB scaled by CHANGE_SCALE, x, y in [-1, 1]), output (gx, gy)
            in working pixels of height per working pixel.
        landscape: whether the lookup reads the sensor in landscape orientation.
        mm_per_pixel: millimetres per working pixel (None: the renderer's own units).
        structure_floors: per :data:`STRUCTURE_BANDS` band, the 99.5th percentile of the
            structured change's two statistics over this family's drifted blank pairs (6
            values), and `structure_threshold`, the same quantile of their combined score;
            a frame whose score is above it shows contact (see :func:`structure_score`).
        unfamiliar_floors, unfamiliar_threshold: the same, set on blank pairs of every
            family's units each recoloured to lie beyond every rendered unit
            (`ratouch.world.sensors.unfamiliar_view`), read through this lookup: what a frame
            from a sensor unlike every rendered unit is held to (none: the family's own).
        meta: provenance and measured figures.
        noise_ref: the median noise (:func:`pair_noise`) of the blank pairs the floors were
            set on; a pair noisier than that has its score against the family's floors
            divided by how much noisier it is (None: read as is, an older file).
        field_floors, field_threshold, field_noise_ref: the same three, set on the same
            blank pairs read with a smooth lighting field removed (:meth:`field_reading`;
            only for :data:`FIELD_CHECK_FAMILIES`; none: not read).
    """

    family: str
    weights: tuple[np.ndarray, ...]
    biases: tuple[np.ndarray, ...]
    landscape: bool
    mm_per_pixel: float | None
    structure_floors: tuple[float, ...] = ()
    structure_threshold: float = float("inf")
    meta: dict = field(default_factory=dict)
    unfamiliar_floors: tuple[float, ...] = ()
    unfamiliar_threshold: float = float("inf")
    noise_ref: float | None = None
    field_floors: tuple[float, ...] = ()
    field_threshold: float = float("inf")
    field_noise_ref: float | None = None
    #: per working size (h, w): the pixel positions the perceptron reads and its output at
    #: zero change there, which depend on nothing else (computed once, not per frame)
    _at_rest: dict = field(default_factory=dict, init=False, compare=False, repr=False)

    @property
    def work_size(self) -> tuple[int, int]:
        """(width, height) the lookup reads frames at."""
        w, h = WORK_LANDSCAPE
        return (w, h) if self.landscape else (h, w)

    def gradients(self, change: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(gx, gy) of a drift-free colour change (h, w, 3) at the working size; no change is
        no gradient (the perceptron's output at zero change, per position, is subtracted)."""
        h, w = change.shape[:2]
        pos, rest = self._rest(h, w)
        x = np.concatenate([change.reshape(-1, 3).T * CHANGE_SCALE, pos], 0)
        g = self._forward(x)
        g -= rest
        return g[0].reshape(h, w), g[1].reshape(h, w)

    def _rest(self, h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
        """(2, h * w) pixel positions in [-1, 1] and the perceptron's (2, h * w) output at
        zero change there."""
        got = self._at_rest.get((h, w))
        if got is None:
            yy, xx = np.meshgrid(np.linspace(-1, 1, h), np.linspace(-1, 1, w), indexing="ij")
            pos = np.stack([xx.ravel(), yy.ravel()])
            rest = self._forward(np.concatenate([np.zeros((3, h * w)), pos], 0))
            got = self._at_rest[(h, w)] = (pos, rest)
        return got

    def _forward(self, x: np.ndarray) -> np.ndarray:
        """The perceptron on (5, n) inputs, one pixel a column: (2, n). A pixel a column,
        each layer is one product `weights.T @ x` (the same sums as a pixel a row, `x @
        weights`: bit-identical, a quarter less time on a frame's 19,200 pixels), the bias and
        the ReLU in place (a third less than with a new array for each), :data:`_COLUMNS`
        pixels at a time (a layer's activations then stay in the CPU's cache: a fifth less
        time, the same sums)."""
        last = len(self.weights) - 1
        out = np.empty((self.weights[-1].shape[1], x.shape[1]))
        for start in range(0, x.shape[1], _COLUMNS):
            y = x[:, start:start + _COLUMNS]
            for n, (wt, b) in enumerate(zip(self.weights, self.biases)):
                y = wt.T @ y
                y += b[:, None]
                if n < last:
                    np.maximum(y, 0, out=y)
            out[:, start:start + _COLUMNS] = y
        return out

    def to_dict(self) -> dict:
        return {"family": self.family, "landscape": self.landscape,
                "mm_per_pixel": self.mm_per_pixel,
                "structure_floors": [float(f"{v:.6g}") for v in self.structure_floors],
                "structure_threshold": self.structure_threshold, "meta": self.meta,
                **({"unfamiliar_floors": [float(f"{v:.6g}") for v in self.unfamiliar_floors],
                    "unfamiliar_threshold": self.unfamiliar_threshold}
                   if self.unfamiliar_floors else {}),
                **({"noise_ref": float(f"{self.noise_ref:.6g}")}
                   if self.noise_ref is not None else {}),
                **({"field_floors": [float(f"{v:.6g}") for v in self.field_floors],
                    "field_threshold": self.field_threshold,
                    "field_noise_ref": float(f"{self.field_noise_ref:.6g}")}
                   if self.field_floors and self.field_noise_ref is not None else {}),
                "weights": [np.round(w, 6).tolist() for w in self.weights],
                "biases": [np.round(b, 6).tolist() for b in self.biases]}

    @classmethod
    def from_dict(cls, d: dict) -> GradientLookup:
        return cls(str(d["family"]), tuple(np.asarray(w, np.float64) for w in d["weights"]),
                   tuple(np.asarray(b, np.float64) for b in d["biases"]), bool(d["landscape"]),
                   None if d["mm_per_pixel"] is None else float(d["mm_per_pixel"]),
                   tuple(float(v) for v in d["structure_floors"]),
                   float(d["structure_threshold"]), dict(d.get("meta", {})),
                   tuple(float(v) for v in d.get("unfamiliar_floors", ())),
                   float(d.get("unfamiliar_threshold", float("inf"))),
                   None if d.get("noise_ref") is None else float(d["noise_ref"]),
                   tuple(float(v) for v in d.get("field_floors", ())),
                   float(d.get("field_threshold", float("inf"))),
                   None if d.get("field_noise_ref") is None else float(d["field_noise_ref"]))

    def with_floors(self, floors: tuple[float, ...], threshold: float,
                    noise_ref: float | None = None, **meta) -> GradientLookup:
        return dataclasses.replace(self, structure_floors=tuple(float(f) for f in floors),
                                   structure_threshold=float(threshold),
                                   noise_ref=self.noise_ref if noise_ref is None
                                   else float(noise_ref),
                                   meta={**self.meta, **meta})

    def with_field_floors(self, floors: tuple[float, ...], threshold: float,
                          noise_ref: float, **meta) -> GradientLookup:
        return dataclasses.replace(self, field_floors=tuple(float(f) for f in floors),
                                   field_threshold=float(threshold),
                                   field_noise_ref=float(noise_ref), meta={**self.meta, **meta})

    def with_unfamiliar_floors(self, floors: tuple[float, ...], threshold: float, **meta
                               ) -> GradientLookup:
        return dataclasses.replace(self, unfamiliar_floors=tuple(float(f) for f in floors),
                                   unfamiliar_threshold=float(threshold),
                                   meta={**self.meta, **meta})

    def change(self, frame: np.ndarray, background: np.ndarray) -> np.ndarray:
        """The frame's drift-free change against `background` at this lookup's working size
        and orientation (a portrait frame of a landscape family is read turned, as the world
        mounts it): what both the height map and the structured change read."""
        turn = (frame.shape[0] > frame.shape[1]) == self.landscape
        return working_change(frame, background, self.work_size, turn=turn)

    def change_and_noise(self, frame: np.ndarray, background: np.ndarray,
                         field: bool = False) -> tuple[np.ndarray, float]:
        """`change(frame, background)` and the pair's noise (:func:`pair_noise`), from one
        drift-free difference; with `field`, a smooth lighting field removed instead of a
        plain gain and offset (:func:`drift_free_change`)."""
        turn = (frame.shape[0] > frame.shape[1]) == self.landscape
        raw = drift_free_change(frame, background, self.work_size, turn=turn, field=field)
        return gaussian_blur(raw, CHANGE_SIGMA), pair_noise(raw)

    def contact(self, frame: np.ndarray, background: np.ndarray,
                change: np.ndarray | None = None, stats: np.ndarray | None = None,
                unfamiliar: bool = False, noise: float | None = None) -> tuple[bool, float]:
        """Whether `frame` shows contact against `background` by its structured change, and
        the score against this family's floors (above :attr:`structure_threshold`: contact),
        or, with `unfamiliar`, against the floors for a sensor unlike every rendered unit
        (:attr:`unfamiliar_floors`; the family's where the lookup has none). Against the
        family's floors a pair noisier than the blanks they were set on (:attr:`noise_ref`)
        has its score divided by how much noisier it is (:func:`noise_adjusted`).
        `change`: `self.change(frame, background)`, `stats`: `band_stats(change)`, `noise`:
        the pair's noise, where already computed (statistics given without the frames and
        without their noise are read as they are)."""
        read_noise = not unfamiliar and self.noise_ref is not None
        if read_noise and noise is None and frame is not None and background is not None:
            change, noise = self.change_and_noise(frame, background)
        if stats is None:
            stats = band_stats(self.change(frame, background) if change is None else change)
        floors, threshold = self.floors_for(unfamiliar)
        score = structure_score(stats, floors)
        if read_noise:
            score = noise_adjusted(score, noise, self.noise_ref)
        return bool(score > threshold), score

    def field_reading(self, frame: np.ndarray, background: np.ndarray
                      ) -> tuple[bool, float] | None:
        """Whether a smooth lighting field alone explains `frame`'s change against
        `background` (a unit whose LEDs glow elsewhere, or light that changed, rather than a
        press), and the score: the change with the field removed against
        :attr:`field_floors`, noise-adjusted as :meth:`contact` is; at or below
        :attr:`field_threshold` the field explains it. None where the lookup has no such
        floors."""
        if not self.field_floors:
            return None
        change, noise = self.change_and_noise(frame, background, field=True)
        score = noise_adjusted(structure_score(band_stats(change), self.field_floors), noise,
                               self.field_noise_ref)
        return not score > self.field_threshold, score

    def floors_for(self, unfamiliar: bool) -> tuple[tuple[float, ...], float]:
        """The structured check's floors and threshold for a frame of this family's units,
        or (`unfamiliar`) of a sensor unlike every rendered unit, where the lookup has such
        floors."""
        if unfamiliar and self.unfamiliar_floors:
            return self.unfamiliar_floors, self.unfamiliar_threshold
        return self.structure_floors, self.structure_threshold


# ------------------------------------------------------------------------- the reading

def working_change(frame: np.ndarray, background: np.ndarray, size: tuple[int, int],
                   turn: bool = False) -> np.ndarray:
    """A frame's colour change against its background at `size` (width, height), [0, 1]
    units, with the global drift removed: per channel, the gain and offset that best map the
    background onto the frame (a robust fit: a press changes a minority of the gel) are
    undone; then a light blur (:data:`CHANGE_SIGMA`).

    Args:
        frame, background: (H, W, 3) uint8 of the same size.
        size: the working size.
        turn: read the frame transposed (a landscape sensor mounted turned, as the world's
            portrait GelSight frames are).

    Raises:
        DataError: the sizes differ.
    """
    return gaussian_blur(drift_free_change(frame, background, size, turn), CHANGE_SIGMA)


def drift_free_change(frame: np.ndarray, background: np.ndarray, size: tuple[int, int],
                      turn: bool = False, field: bool = False) -> np.ndarray:
    """`working_change` before its light blur: the frame against its background at `size`,
    per channel the robustly fitted gain and offset undone; with `field`, each of them a
    quadratic in the position (a smooth lighting field, :func:`_robust_field`).

    Raises:
        DataError: the sizes differ.
    """
    check_background_size(background.shape[1::-1], frame.shape[1::-1], "the background")
    if turn:
        frame, background = frame.transpose(1, 0, 2), background.transpose(1, 0, 2)
    f = _resize3(frame, size)
    b = _resize3(background, size)
    out = np.empty_like(f)
    fit = _robust_field if field else _robust_affine
    for c in range(3):
        out[..., c] = f[..., c] - fit(b[..., c], f[..., c])
    return out


def pair_noise(raw: np.ndarray) -> float:
    """A frame-and-background pair's noise: the robust spread (1.4826 x the median absolute
    deviation) of the 1-px high-pass (a pixel less the mean of its four neighbours) of its
    drift-free change before the blur (`drift_free_change`), mean over channels. A press's
    change, blurred by the gel and the optics, carries little at one pixel; camera noise
    carries most of its energy there."""
    hp = raw[1:-1, 1:-1] - 0.25 * (raw[:-2, 1:-1] + raw[2:, 1:-1] + raw[1:-1, :-2]
                                    + raw[1:-1, 2:])
    flat = hp.reshape(-1, hp.shape[-1])
    dev = np.abs(flat - np.median(flat, axis=0))
    return float(np.mean(1.4826 * np.median(dev, axis=0)))


def noise_adjusted(score: float, noise: float | None, noise_ref: float | None) -> float:
    """A structured score against a family's floors, divided by how much noisier the pair is
    than the blank pairs the floors were set on (unchanged where it is not noisier, or where
    either noise is unknown)."""
    if noise is None or noise_ref is None or noise_ref <= 0 or not np.isfinite(noise):
        return score
    return score / max(1.0, noise / noise_ref)


def _resize3(a: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    a = np.asarray(a)
    return np.stack([resize_array(np.ascontiguousarray(a[..., c], np.float32), size)
                     for c in range(3)], -1).astype(np.float64) / 255.0


def _robust_affine(x: np.ndarray, y: np.ndarray, rounds: int = 3) -> np.ndarray:
    """gain * x + offset fitted to y by least squares, refitted on the pixels whose residual
    is within 2.5 robust deviations (the press is left out)."""
    xv, yv = x.ravel(), y.ravel()
    keep = np.ones(xv.shape, bool)
    gain, offset = 1.0, 0.0
    for n in range(rounds):
        xs, ys = xv[keep], yv[keep]
        var = xs.var()
        gain = float(((xs - xs.mean()) * (ys - ys.mean())).mean() / var) if var > 1e-10 else 1.0
        gain = float(np.clip(gain, 0.8, 1.25))
        offset = float(ys.mean() - gain * xs.mean())
        if n == rounds - 1:  # the last fit's pixels to keep would be read by no one
            break
        keep = _inliers(yv - (gain * xv + offset))
    return gain * x + offset


def _inliers(r: np.ndarray) -> np.ndarray:
    """The pixels a robust refit keeps, from the last fit's residuals `r`: those within 2.5
    robust deviations (the press is left out), never fewer than a third of the gel (else the
    third with the smallest residuals)."""
    spread = np.abs(r - np.median(r))
    mad = np.median(spread) * 1.4826 + 1e-6
    keep = spread < 2.5 * mad
    if keep.sum() < 0.3 * keep.size:
        keep = np.abs(r) <= np.quantile(np.abs(r), 0.3)
    return keep


@functools.lru_cache(maxsize=8)
def _quadratic_terms(h: int, w: int) -> np.ndarray:
    """(h * w, 6) 1, u, v, u², uv, v² over a (h, w) grid, u and v in [-1, 1] (read only)."""
    v, u = np.meshgrid(np.linspace(-1, 1, h), np.linspace(-1, 1, w), indexing="ij")
    out = np.stack([np.ones_like(u), u, v, u * u, u * v, v * v], -1).reshape(-1, 6)
    out.setflags(write=False)
    return out


def _robust_field(x: np.ndarray, y: np.ndarray, rounds: int = 3) -> np.ndarray:
    """g(u, v) * x + o(u, v) fitted to y by least squares, g and o each a quadratic in the
    position (u, v in [-1, 1]), refitted as :func:`_robust_affine` is on the pixels whose
    residual is within 2.5 robust deviations (the press is left out)."""
    h, w = x.shape
    poly = _quadratic_terms(h, w)
    design = np.concatenate([poly * x.reshape(-1, 1), poly], 1)
    yv = y.ravel()
    keep = np.ones(yv.shape, bool)
    coef = np.zeros(design.shape[1])
    for n in range(rounds):
        a = design[keep]  # normal equations: 12 unknowns, well scaled
        coef = np.linalg.solve(a.T @ a + 1e-12 * np.eye(a.shape[1]), a.T @ yv[keep])
        if n == rounds - 1:
            break
        keep = _inliers(yv - design @ coef)
    return (design @ coef).reshape(h, w)


def integrate(gx: np.ndarray, gy: np.ndarray) -> np.ndarray:
    """The height map whose gradient best matches (gx, gy) in least squares (Frankot and
    Chellappa's projection onto integrable fields, on the field mirrored to be periodic, so
    that the frame's borders do not wrap around). Height in the gradients' pixel units; its
    mean is 0."""
    gx = np.asarray(gx, np.float64)
    gy = np.asarray(gy, np.float64)
    h, w = gx.shape
    # mirror: x-derivatives change sign under a left-right flip, y under an up-down flip
    GX = np.block([[gx, -gx[:, ::-1]], [gx[::-1, :], -gx[::-1, ::-1]]])
    GY = np.block([[gy, gy[:, ::-1]], [-gy[::-1, :], -gy[::-1, ::-1]]])
    # the mirrored field is real: its half spectrum (rfft2) holds it all, at a third of the
    # time of the full one. The derivative at a Nyquist frequency (x's last column, y's middle
    # row) takes no part: it is anti-symmetric there, and the real part of the full inverse
    # (what this computed before) cancels it; the two agree to 1e-15.
    u = np.fft.rfftfreq(2 * w) * 2 * np.pi
    v = np.fft.fftfreq(2 * h) * 2 * np.pi
    U, V = np.meshgrid(u, v)
    den = U * U + V * V
    den[0, 0] = 1.0
    U[:, w] = 0.0
    V[h, :] = 0.0
    Z = (-1j * U * np.fft.rfft2(GX) - 1j * V * np.fft.rfft2(GY)) / den
    Z[0, 0] = 0.0
    return np.fft.irfft2(Z, s=(2 * h, 2 * w))[:h, :w]


@dataclass(frozen=True)
class HeightMap:
    """A press read as geometry.

    Attributes:
        height: (h, w) height pushed in (towards the camera is positive), in `units`, at the
            lookup's working size and orientation; 0 at its median.
        depth: 99.5th percentile of the height (how far the gel is pushed in).
        spread: share of the gel pushed in by more than a third of the depth.
        relief: RMS of the height's detail (texture).
        units: "mm" for a calibrated sensor, else "render units".
        family: the lookup's family.
    """

    height: np.ndarray
    depth: float
    spread: float
    relief: float
    units: str
    family: str

    def to_dict(self) -> dict:
        return {"family": self.family, "units": self.units, "depth": round(self.depth, 4),
                "spread": round(self.spread, 4), "relief": round(self.relief, 5)}

    def image(self, scale: float | None = None) -> np.ndarray:
        """(h, w, 3) uint8 picture of the height map: dark is flat, bright is pushed in, on
        a fixed scale (`scale`, the units' height shown white; default the depth or the
        noise-floor-like 1e-3 whichever is larger) so that a blank stays dark."""
        top = max(self.depth, 1e-3) if scale is None else scale
        v = np.clip(self.height / top, 0, 1)
        # a cool-to-warm ramp: black, blue, orange, white
        r = np.clip(2.2 * v - 0.6, 0, 1)
        g = np.clip(2.0 * v - 1.0, 0, 1) * 0.85 + 0.15 * v
        b = np.clip(1.6 * v, 0, 1) * (1 - v) + v * v
        return (np.stack([r, g, b], -1) * 255 + 0.5).astype(np.uint8)


def read_height(lookup: GradientLookup, frame: np.ndarray, background: np.ndarray,
                change: np.ndarray | None = None) -> HeightMap:
    """Read a frame against its background as a height map with `lookup` (see the module);
    `change`: `lookup.change(frame, background)` where already computed.

    Raises:
        DataError: the sizes differ.
    """
    if change is None:
        change = lookup.change(frame, background)
    gx, gy = lookup.gradients(change)
    z = integrate(gx, gy)
    z = z - np.median(z)
    scale = 1.0 if lookup.mm_per_pixel is None else lookup.mm_per_pixel
    z = z * scale
    depth = float(np.percentile(z, 99.5))
    spread = float((z > depth / 3).mean()) if depth > 0 else 0.0
    detail = z - gaussian_blur(z, RELIEF_SIGMA)
    relief = float(np.sqrt(np.mean(detail * detail)))
    return HeightMap(z.astype(np.float32), depth, spread, relief,
                     "mm" if lookup.mm_per_pixel is not None else "render units",
                     lookup.family)


# ------------------------------------------------------------------- structured change

#: Band-passes (working-pixel sigmas) of the structured change: edges, texture, small caps.
STRUCTURE_BANDS = ((1.0, 3.0), (2.0, 6.0), (3.0, 10.0))
#: Sensor families whose units differ by a smooth lighting field (where and how brightly
#: their LEDs glow) that a per-channel gain and offset cannot undo: where the structured check
#: calls contact, the change is read again with that field removed, against floors of its own
#: (`GradientLookup.field_reading`), and a change the field alone explains is "uncertain"
#: (docs/geometry.md). The GelSight's and the Mini's units differ by markers and noise.
FIELD_CHECK_FAMILIES = ("digit",)
#: Sensor families whose blank frames, read against another unit's background, can score
#: just above the structured threshold (the tail of blank noise, not a lighting field): there
#: a structured contact scoring at most :data:`BAND_FACTOR` x the family's threshold is
#: "uncertain", never "no contact" (docs/geometry.md, "A Mini blank just over the structured
#: floor"). Read with the family's floors only: a sensor beyond every rendered unit has its own.
BAND_FAMILIES = ("mini",)
#: The top of that band, as a multiple of the family's structured threshold: a round number,
#: not fitted (on the development look the Mini's blanks reach 1.19 x, its rendered presses
#: start at 2.35 x).
BAND_FACTOR = 2.0


def band_stats(c: np.ndarray) -> np.ndarray:
    """Structured local change of a drift-free change (`GradientLookup.change`): per band of
    :data:`STRUCTURE_BANDS`, the 99.5th percentile and the RMS of |band-pass| (mean over
    channels). (6,) float64, [0, 1] units."""
    blurred = {s: gaussian_blur(c, s) for s in sorted({x for b in STRUCTURE_BANDS for x in b})}
    out = []
    for lo, hi in STRUCTURE_BANDS:
        d = np.abs(blurred[lo] - blurred[hi]).mean(2)
        out += [float(np.percentile(d, 99.5)), float(np.sqrt(np.mean(d * d)))]
    return np.asarray(out, np.float64)


def structure_score(stats: np.ndarray, floors: tuple[float, ...]) -> float:
    """How far the structured change stands above a family's blank floors: the largest ratio
    of a statistic to its floor (1: at the floor)."""
    if not floors:
        return float("nan")
    return float(np.max(np.asarray(stats) / np.maximum(np.asarray(floors), 1e-9)))


# ------------------------------------------------------------------- firmness from shape

#: Scales (working px) the height map's detail is measured at, for :func:`shape_features`.
SHAPE_SCALES = (1.0, 2.0, 4.0, 8.0)
#: Names of :func:`shape_features`' numbers, in order.
SHAPE_FEATURES = (
    "log depth", "spread", "log relief / depth", "log p99 slope / depth",
    "log p90 slope / depth", "height / depth q50", "height / depth q75", "height / depth q90",
    "height / depth q95", *(f"log detail s{s:g} / depth" for s in SHAPE_SCALES),
    "log detail inside / depth",
    *(f"log band {lo:g}-{hi:g} {stat}" for lo, hi in ((1, 3), (2, 6), (3, 10))
      for stat in ("p99.5", "rms")))


def shape_features(hm: HeightMap, change: np.ndarray, stats: np.ndarray | None = None
                   ) -> np.ndarray:
    """What a press's shape and its change's texture say about firmness: the height map's
    profile (its depth, spread, relief, slopes and detail at :data:`SHAPE_SCALES`, each as a
    log ratio to the depth, and quantiles of height over depth: a rigid thing pushes a
    steep-edged, textured dent, a compliant one a wide, smooth-edged one) and the drift-free
    change's structured statistics (:func:`band_stats`, log). (20,) float64, named by
    :data:`SHAPE_FEATURES`; per family (the depth is in its units). `stats`:
    `band_stats(change)` where already computed."""
    z = hm.height.astype(np.float64)
    d = max(hm.depth, 1e-6)
    gy, gx = np.gradient(z)
    slope = np.hypot(gx, gy)
    f = [np.log(d), hm.spread, np.log(max(hm.relief, 1e-7) / d),
         np.log(np.percentile(slope, 99) / d + 1e-9), np.log(np.percentile(slope, 90) / d + 1e-9)]
    f += [float(q) for q in np.quantile(np.clip(z / d, -1, 2), [0.5, 0.75, 0.9, 0.95])]
    for s in SHAPE_SCALES:
        detail = z - gaussian_blur(z, s)
        f.append(np.log(np.sqrt(np.mean(detail * detail)) / d + 1e-9))
    inside = z > d / 3
    detail = z - gaussian_blur(z, 2.0)
    f.append(np.log(np.sqrt(np.mean(detail[inside] ** 2)) / d + 1e-9)
             if inside.sum() > 5 else -10.0)
    f += [float(v) for v in np.log((band_stats(change) if stats is None else stats) + 1e-6)]
    return np.nan_to_num(np.asarray(f, np.float64), nan=0.0, posinf=0.0, neginf=-20.0)


def press_shape(lookup: GradientLookup, frame: np.ndarray, background: np.ndarray
                ) -> np.ndarray:
    """:func:`shape_features` of a frame read against its background by `lookup`."""
    change = lookup.change(frame, background)
    return shape_features(read_height(lookup, frame, background, change), change)


@dataclass(frozen=True)
class FirmnessModel:
    """One family's reading of firmness from shape: a logistic model on standardised
    :func:`shape_features`, fitted on renders of everyday presses (`ratouch train
    geometry`); its probability is that the pressed thing is soft (compliance >= 0.5).

    Attributes:
        family: the sensor family.
        mean, scale: the features' standardisation.
        coef, bias: the logistic model.
        meta: provenance and measured figures.
    """

    family: str
    mean: np.ndarray
    scale: np.ndarray
    coef: np.ndarray
    bias: float
    meta: dict = field(default_factory=dict)

    def soft(self, features: np.ndarray) -> float:
        """Probability that the press is of a soft thing."""
        x = (np.asarray(features, np.float64) - self.mean) / self.scale
        return float(1.0 / (1.0 + np.exp(-np.clip(x @ self.coef + self.bias, -30, 30))))

    def read(self, features: np.ndarray) -> dict:
        """{"soft": probability, "reads": "soft" or "hard" (at 0.5)}."""
        p = self.soft(features)
        return {"soft": round(p, 3), "reads": "soft" if p >= 0.5 else "hard"}

    def to_dict(self) -> dict:
        return {"family": self.family, "features": list(SHAPE_FEATURES),
                "mean": np.round(self.mean, 6).tolist(),
                "scale": np.round(self.scale, 6).tolist(),
                "coef": np.round(self.coef, 6).tolist(), "bias": round(self.bias, 6),
                "meta": self.meta}

    @classmethod
    def from_dict(cls, d: dict) -> FirmnessModel:
        if list(d.get("features", [])) != list(SHAPE_FEATURES):
            raise ValueError("its firmness model reads other shape features")
        return cls(str(d["family"]), np.asarray(d["mean"], np.float64),
                   np.asarray(d["scale"], np.float64), np.asarray(d["coef"], np.float64),
                   float(d["bias"]), dict(d.get("meta", {})))


@dataclass(frozen=True)
class RoutedFirmness:
    """One family's firmness read in two regimes of press: everyday presses (broad, shallow,
    thin, edged: `ratouch.world.presses`) and the world's own frames (a material pressed
    firmly, its compliance in the patch's size and edge), where the same shape means another
    firmness. A router (a logistic model on the same features; its probability: that the
    press is of the world's regime) mixes the two models' probabilities.

    Attributes:
        family: the sensor family.
        everyday, world: the regimes' firmness models.
        router: the logistic model whose probability is the world regime's weight.
        meta: provenance and measured figures.
    """

    family: str
    everyday: FirmnessModel
    world: FirmnessModel
    router: FirmnessModel
    meta: dict = field(default_factory=dict)

    def regime(self, features: np.ndarray) -> float:
        """Probability that the press is of the world's regime."""
        return self.router.soft(features)

    def soft(self, features: np.ndarray) -> float:
        """Probability that the press is of a soft thing: the regimes' mixed by the router."""
        return self._mixed(features, self.regime(features))

    def _mixed(self, features: np.ndarray, r: float) -> float:
        return (1 - r) * self.everyday.soft(features) + r * self.world.soft(features)

    def read(self, features: np.ndarray) -> dict:
        """{"soft": probability, "reads": "soft" or "hard" (at 0.5), "regime": "world" or
        "everyday" (the router at 0.5)}."""
        r = self.regime(features)  # read once: it weighs the mix and names the regime
        p = self._mixed(features, r)
        return {"soft": round(p, 3), "reads": "soft" if p >= 0.5 else "hard",
                "regime": "world" if r >= 0.5 else "everyday"}

    def to_dict(self) -> dict:
        return {"family": self.family, "kind": "routed", "meta": self.meta,
                "everyday": self.everyday.to_dict(), "world": self.world.to_dict(),
                "router": self.router.to_dict()}

    @classmethod
    def from_dict(cls, d: dict) -> RoutedFirmness:
        return cls(str(d["family"]), FirmnessModel.from_dict(d["everyday"]),
                   FirmnessModel.from_dict(d["world"]), FirmnessModel.from_dict(d["router"]),
                   dict(d.get("meta", {})))


def firmness_from_dict(d: dict) -> FirmnessModel | RoutedFirmness:
    """A family's firmness model as saved (`to_dict`), of either kind."""
    return (RoutedFirmness.from_dict(d) if d.get("kind") == "routed"
            else FirmnessModel.from_dict(d))


# ----------------------------------------------------------------------- the calibration

@dataclass(frozen=True)
class GeometryCalibration:
    """Every family's lookup and firmness model (a family may have none), with provenance."""

    lookups: dict[str, GradientLookup]
    meta: dict = field(default_factory=dict)
    firmness: dict[str, FirmnessModel | RoutedFirmness] = field(default_factory=dict)

    def lookup(self, family: str) -> GradientLookup | None:
        return self.lookups.get(family)

    def read_firmness(self, family: str, hm: HeightMap, change: np.ndarray,
                      stats: np.ndarray | None = None) -> dict | None:
        """`family`'s firmness reading of a press (`FirmnessModel.read`; `stats`:
        `band_stats(change)` where already computed), or None (no model for the family)."""
        model = self.firmness.get(family)
        return None if model is None else model.read(shape_features(hm, change, stats))

    def save(self, path: str | os.PathLike) -> Path:
        body = {"format": FORMAT, "meta": self.meta,
                "lookups": {k: v.to_dict() for k, v in self.lookups.items()},
                "firmness": {k: v.to_dict() for k, v in self.firmness.items()}}
        return write_atomic(path, json.dumps(body, indent=1) + "\n")

    @classmethod
    def load(cls, path: str | os.PathLike) -> GeometryCalibration:
        """Raises:
            DataNotFoundError: no file.
            DataError: not a geometry calibration.
        """
        path = Path(path)
        if not path.is_file():
            raise DataNotFoundError(
                f"no geometry calibration at {path} (`ratouch train geometry`)")
        try:
            d = json.loads(path.read_text(encoding="utf-8"))
            if d.get("format") != FORMAT:
                raise ValueError(f"format {d.get('format')!r}, expected {FORMAT!r}")
            return cls({k: GradientLookup.from_dict(v) for k, v in d["lookups"].items()},
                       dict(d.get("meta", {})),
                       {k: firmness_from_dict(v) for k, v in d.get("firmness", {}).items()})
        except (ValueError, KeyError, TypeError, UnicodeDecodeError) as e:
            raise DataError(f"{path} is not a geometry calibration: {e}") from e


def fit_lookup(family: str, changes: list[np.ndarray], targets: list[np.ndarray],
               masks: list[np.ndarray], landscape: bool, mm_per_pixel: float | None,
               seed: int = 0, samples: int = 120_000, hidden: tuple[int, ...] = (32, 32),
               meta: dict | None = None) -> GradientLookup:
    """Fit a family's lookup on drift-free colour changes (h, w, 3) and their known gradients
    (h, w, 2), on the pixels of `masks` (h, w) bool (pixels near a contact's rim, where the
    annotation is least sure, are best left out by the caller)."""
    from sklearn.neural_network import MLPRegressor

    rng = np.random.default_rng(seed)
    xs, ys = [], []
    for change, target, mask in zip(changes, targets, masks):
        h, w = change.shape[:2]
        yy, xx = np.meshgrid(np.linspace(-1, 1, h), np.linspace(-1, 1, w), indexing="ij")
        x = np.concatenate([change.reshape(-1, 3) * CHANGE_SCALE,
                            xx.reshape(-1, 1), yy.reshape(-1, 1)], 1)
        idx = np.flatnonzero(mask.ravel())
        xs.append(x[idx])
        ys.append(target.reshape(-1, 2)[idx])
    X, Y = np.concatenate(xs), np.concatenate(ys)
    if len(X) > samples:
        pick = rng.choice(len(X), samples, replace=False)
        X, Y = X[pick], Y[pick]
    mlp = MLPRegressor(hidden_layer_sizes=hidden, max_iter=80, random_state=seed,
                       early_stopping=True, n_iter_no_change=8)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a stop at max_iter is a budget, not an error
        mlp.fit(X, Y)
    return GradientLookup(family, tuple(np.asarray(w) for w in mlp.coefs_),
                          tuple(np.asarray(b) for b in mlp.intercepts_), landscape,
                          mm_per_pixel, meta={**(meta or {}),
                                              "fit_r2": round(float(mlp.score(X, Y)), 4),
                                              "fit_pixels": int(len(X))})


def sphere_gradients(hw: tuple[int, int], centre: tuple[float, float], radius: float,
                     ball: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The gradient (h, w, 2) of a ball of radius `ball` pressed in with a contact circle of
    `radius` at `centre` (x, y), all in working pixels, zero outside the contact, and the
    height (h, w) of the cap (its known depth is the value at the centre)."""
    h, w = hw
    yy, xx = np.mgrid[:h, :w].astype(np.float64)
    dx, dy = xx - centre[0], yy - centre[1]
    d2 = dx * dx + dy * dy
    inside = d2 < radius * radius
    zz = np.sqrt(np.maximum(ball * ball - d2, 1e-9))
    g = np.stack([np.where(inside, -dx / zz, 0.0), np.where(inside, -dy / zz, 0.0)], -1)
    cap = np.where(inside, zz - np.sqrt(max(ball * ball - radius * radius, 0.0)), 0.0)
    return g, cap, inside
