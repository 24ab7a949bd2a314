"""The library's one resize (`ratouch.images.resize_array`)."""

import numpy as np
from PIL import Image

from ratouch.images import resize_array


def test_resize_keeps_dtype_and_matches_pil():
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (30, 40, 3), dtype=np.uint8)
    out = resize_array(rgb, (20, 10))
    assert out.shape == (10, 20, 3) and out.dtype == np.uint8
    ref = np.asarray(Image.fromarray(rgb).resize((20, 10), Image.Resampling.BILINEAR))
    assert np.array_equal(out, ref)
    plane = rng.normal(size=(30, 40)).astype(np.float32)
    small = resize_array(plane, 8)
    assert small.shape == (8, 8) and small.dtype == np.float32
    assert abs(float(small.mean()) - float(plane.mean())) < 0.2


def test_resize_same_size_is_the_array_and_filters_apply():
    rgb = np.zeros((12, 12, 3), np.uint8)
    rgb[::2] = 255
    assert resize_array(rgb, 12) is rgb
    nearest = resize_array(rgb, 24, Image.Resampling.NEAREST)
    assert set(np.unique(nearest)) == {0, 255}
    two_step = resize_array(np.repeat(np.repeat(rgb, 20, 0), 20, 1), 6, reducing_gap=2.0)
    assert two_step.shape == (6, 6, 3)
