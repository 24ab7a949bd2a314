"""Tests of the pure-numpy silhouette rasteriser (ratouch.world.silhouette)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from ratouch.world.silhouette import (
    FAMILIES,
    fill_fraction,
    mask_bbox,
    natural_aspect,
    silhouette_mask,
)

HW = (128, 128)
DEFAULT = (0.5, 0.5, 0.5, 0.5)
VARIANTS = [DEFAULT, (0.0, 0.0, 0.0, 0.0), (1.0, 1.0, 1.0, 1.0), (0.2, 0.8, 0.35, 0.65)]
CORNERS = [tuple(float(t) for t in v) for v in itertools.product((0.0, 1.0), repeat=4)]
SIZES = (13, 16, 20, 28, 40, 64, 90, 120)
CASES = [(DEFAULT, False), ((0.0,) * 4, True), ((1.0,) * 4, False), ((0.3, 0.7, 0.6, 0.2), True)]


def _bbox_error(mask: np.ndarray, bbox: tuple[float, float, float, float]) -> float:
    got = mask_bbox(mask)
    assert got is not None, f"empty mask for bbox {bbox}"
    return max(abs(g - b) for g, b in zip(got, bbox))


def _centred(
    w: float, h: float, cx: float = 64.3, cy: float = 63.6
) -> tuple[float, float, float, float]:
    return (cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2)


def test_at_least_twenty_distinct_families() -> None:
    assert len(FAMILIES) >= 20
    assert len(set(FAMILIES)) == len(FAMILIES)
    assert all(isinstance(f, str) and f for f in FAMILIES)
    for name in ("ball", "egg", "box", "bottle", "mug", "chair", "table", "teddy", "blob"):
        assert name in FAMILIES


@pytest.mark.parametrize("family", FAMILIES)
@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("flip", [False, True])
def test_mask_is_nonempty_bool_of_requested_shape(family: str, variant: tuple, flip: bool) -> None:
    mask = silhouette_mask(family, (96, 128), (10.0, 12.0, 110.0, 80.0), variant, flip)
    assert mask.dtype == np.bool_
    assert mask.shape == (96, 128)
    assert mask.any()


@pytest.mark.parametrize("family", FAMILIES)
def test_tight_bbox_matches_request_square_and_natural(family: str) -> None:
    worst = 0.0
    for size in SIZES:
        for variant, flip in CASES:
            aspect = natural_aspect(family, variant)
            w, h = (size, size / aspect) if aspect >= 1.0 else (size * aspect, size)
            w, h = max(w, 6.0), max(h, 6.0)
            for bbox in (_centred(size, size), _centred(w, h), (3.0, 5.0, 3.0 + size, 5.0 + size)):
                mask = silhouette_mask(family, HW, bbox, variant, flip)
                err = _bbox_error(mask, bbox)
                assert err <= 1.5, f"{family} {variant} flip={flip} {bbox}: off by {err:.2f} px"
                worst = max(worst, err)
    assert worst <= 1.5


@pytest.mark.parametrize("family", FAMILIES)
def test_tight_bbox_matches_request_random_boxes(family: str) -> None:
    rng = np.random.default_rng(sum(map(ord, family)))
    for _ in range(25):
        w, h = rng.uniform(13.0, 120.0, size=2)
        x0, y0 = rng.uniform(0.0, 128.0 - w), rng.uniform(0.0, 128.0 - h)
        bbox = (float(x0), float(y0), float(x0 + w), float(y0 + h))
        variant = rng.random(4)
        flip = bool(rng.integers(2))
        err = _bbox_error(silhouette_mask(family, HW, bbox, variant, flip), bbox)
        assert err <= 1.5, f"{family} {np.round(variant, 2)} flip={flip} bbox={bbox}: {err:.2f} px"


@pytest.mark.parametrize("family", FAMILIES)
def test_fill_fraction_in_range(family: str) -> None:
    rng = np.random.default_rng(7)
    variants = [DEFAULT, *CORNERS, *(tuple(rng.random(4)) for _ in range(4))]
    for variant in variants:
        frac = fill_fraction(family, variant)
        assert 0.2 <= frac <= 0.97, f"{family} {variant}: fill {frac:.3f}"
    mask = silhouette_mask(family, (64, 64), (0.0, 0.0, 64.0, 64.0))
    assert fill_fraction(family) == pytest.approx(mask.mean())


@pytest.mark.parametrize("family", FAMILIES)
def test_deterministic(family: str) -> None:
    bbox = (7.3, 20.8, 101.6, 111.1)
    a = silhouette_mask(family, HW, bbox, (0.1, 0.9, 0.4, 0.6), True)
    b = silhouette_mask(family, HW, bbox, np.array([0.1, 0.9, 0.4, 0.6]), True)
    assert np.array_equal(a, b)


@pytest.mark.parametrize("family", FAMILIES)
def test_flip_mirrors(family: str) -> None:
    variant = (0.3, 0.6, 0.8, 0.1)
    # A bbox symmetric about the image's vertical centre line: flip == mirrored image.
    bbox = (20.0, 15.0, 108.0, 100.0)
    plain = silhouette_mask(family, HW, bbox, variant)
    flipped = silhouette_mask(family, HW, bbox, variant, flip=True)
    assert np.array_equal(flipped, plain[:, ::-1])
    # Any integer bbox: the bbox's columns are mirrored in place.
    x0, x1 = 5, 70
    bbox = (float(x0), 40.0, float(x1), 90.0)
    plain = silhouette_mask(family, HW, bbox, variant)
    flipped = silhouette_mask(family, HW, bbox, variant, flip=True)
    assert np.array_equal(flipped[:, x0:x1], plain[:, x0:x1][:, ::-1])
    assert not flipped[:, :x0].any() and not flipped[:, x1:].any()


@pytest.mark.parametrize("family", FAMILIES)
def test_partially_outside_bbox_is_clipped(family: str) -> None:
    bbox = (-30.0, -20.0, 60.0, 70.0)
    mask = silhouette_mask(family, HW, bbox)
    assert mask.shape == HW and mask.any()
    # Same shape on a larger canvas, shifted so that all of it is inside: crops agree.
    big = silhouette_mask(family, (228, 228), (70.0, 80.0, 160.0, 170.0))
    crop = big[100:228, 100:228]
    assert (mask != crop).sum() <= 0.01 * crop.sum() + 2
    got = mask_bbox(mask)
    assert got is not None and got[2] <= 61.5 and got[3] <= 71.5
    # Overhanging the far corner, and entirely outside.
    assert silhouette_mask(family, HW, (100.0, 90.0, 170.0, 150.0)).any()
    assert not silhouette_mask(family, HW, (130.0, 10.0, 170.0, 50.0)).any()
    assert not silhouette_mask(family, HW, (-50.0, -50.0, -1.0, -1.0)).any()


@pytest.mark.parametrize("family", FAMILIES)
def test_variant_changes_shape(family: str) -> None:
    bbox = (10.0, 10.0, 118.0, 118.0)
    a = silhouette_mask(family, HW, bbox, (0.0, 0.0, 0.0, 0.0))
    b = silhouette_mask(family, HW, bbox, (1.0, 1.0, 1.0, 1.0))
    assert not np.array_equal(a, b)


def test_variant_values_are_clipped() -> None:
    bbox = (10.0, 10.0, 100.0, 90.0)
    a = silhouette_mask("shirt", HW, bbox, (-1.0, 2.0, 0.5, 7.0))
    b = silhouette_mask("shirt", HW, bbox, (0.0, 1.0, 0.5, 1.0))
    assert np.array_equal(a, b)


@pytest.mark.parametrize(
    "bbox",
    [
        (10.0, 10.0, 118.0, 118.0),
        (4.0, 34.0, 124.0, 94.0),
        (34.0, 4.0, 94.0, 124.0),
        (50.0, 50.0, 72.0, 72.0),
    ],
)
def test_families_are_pairwise_distinguishable(bbox: tuple[float, float, float, float]) -> None:
    masks = {f: silhouette_mask(f, HW, bbox) for f in FAMILIES}
    for a, b in itertools.combinations(FAMILIES, 2):
        iou = (masks[a] & masks[b]).sum() / (masks[a] | masks[b]).sum()
        assert iou < 0.9, f"{a} vs {b}: IoU {iou:.3f}"


def test_unknown_family_raises_with_name_and_choices() -> None:
    with pytest.raises(ValueError) as info:
        silhouette_mask("spaceship", HW, (0.0, 0.0, 10.0, 10.0))
    message = str(info.value)
    assert "spaceship" in message
    assert "ball" in message and "teddy" in message
    with pytest.raises(ValueError, match="spaceship"):
        fill_fraction("spaceship")


@pytest.mark.parametrize(
    "bbox", [(10.0, 10.0, 10.0, 20.0), (10.0, 10.0, 20.0, 5.0), (30.0, 5.0, 20.0, 50.0)]
)
def test_degenerate_bbox_raises(bbox: tuple[float, float, float, float]) -> None:
    with pytest.raises(ValueError) as info:
        silhouette_mask("ball", HW, bbox)
    assert repr(bbox) in str(info.value)


def test_other_bad_arguments_raise() -> None:
    with pytest.raises(ValueError, match="finite"):
        silhouette_mask("ball", HW, (0.0, 0.0, float("nan"), 10.0))
    with pytest.raises(ValueError, match="variant"):
        silhouette_mask("ball", HW, (0.0, 0.0, 10.0, 10.0), (0.5, 0.5))
    with pytest.raises(ValueError, match="variant"):
        silhouette_mask("ball", HW, (0.0, 0.0, 10.0, 10.0), (0.5, 0.5, float("inf"), 0.5))
    with pytest.raises(ValueError, match="bbox"):
        silhouette_mask("ball", HW, (0.0, 0.0, 10.0))  # type: ignore[arg-type]


def test_mask_bbox() -> None:
    mask = np.zeros((10, 12), dtype=bool)
    assert mask_bbox(mask) is None
    mask[2:5, 3:9] = True
    mask[7, 1] = True
    assert mask_bbox(mask) == (1, 2, 9, 8)
    assert mask_bbox(mask.astype(np.uint8)) == (1, 2, 9, 8)
    with pytest.raises(ValueError):
        mask_bbox(np.zeros((2, 2, 2), dtype=bool))


def test_natural_aspect_is_positive_and_plausible() -> None:
    for family in FAMILIES:
        assert 0.1 < natural_aspect(family) < 10.0
    assert natural_aspect("spoon") > 2.0  # long and thin
    assert natural_aspect("bottle") < 0.8  # tall


def test_xpoly_samples_each_column_between_its_top_and_bottom() -> None:
    """`XPoly` (a `YPoly` rendered on the transposed grid): without growing, pixel (j, i) is
    inside exactly when yt(x_i) <= y_j <= yb(x_i), with yt, yb piecewise linear, for x_i
    within [xs[0], xs[-1]]; its extent is (xs[0], min yt, xs[-1], max yb)."""
    from ratouch.world.silhouette.primitives import Grid, XPoly

    rng = np.random.default_rng(3)
    for _ in range(20):
        xs = np.sort(rng.random(5)) * 10
        yt = rng.random(5) * 4
        yb = yt + 0.5 + rng.random(5) * 4
        g = Grid(-0.5, -0.5, 0.21, 0.17, 55, 60)
        p = XPoly(xs, yt, yb)
        assert p.ext == (xs[0], yt.min(), xs[-1], yb.max())
        full = np.zeros((g.ny, g.nx), bool)
        out = p.render(g, grow=False)
        if out is not None:
            i0, i1, j0, j1, mask = out
            full[j0:j1, i0:i1] = mask
        inside_x = (g.X >= xs[0]) & (g.X <= xs[-1])
        top, bot = np.interp(g.X, xs, yt), np.interp(g.X, xs, yb)
        expected = (g.Y[:, None] >= top) & (g.Y[:, None] <= bot) & inside_x
        assert np.array_equal(full, expected)
