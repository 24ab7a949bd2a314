"""The library's one resize (`ratouch.images.resize_array`) and one blur (`gaussian_blur`)."""

import numpy as np
import pytest
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


@pytest.mark.parametrize("shape,dtype", [((120, 160, 3), np.float64), ((128, 96, 3), np.float32),
                                         ((160, 120), np.float64), ((7, 5), np.float64)])
@pytest.mark.parametrize("sigma", [0.7, 1.0, 2.0, 3.0, 8.0, 20.0])
def test_gaussian_blur_is_scipys_filter_over_the_two_spatial_axes(shape, dtype, sigma):
    """The one blur of image arrays: scipy.ndimage.gaussian_filter(a, (s, s[, 0])) (mirrored
    boundaries, 4 sigmas), in the input's dtype: exactly below BLUR_MATRIX_FROM, up to the
    order of the sums from it on (a matrix product per axis), kernels wider than the image
    included."""
    from scipy.ndimage import gaussian_filter

    from ratouch.images import BLUR_MATRIX_FROM, gaussian_blur

    a = np.random.default_rng(0).random(shape).astype(dtype)
    ref = gaussian_filter(a, (sigma, sigma, 0)[:a.ndim])
    got = gaussian_blur(a, sigma)
    assert got.dtype == a.dtype and got.shape == a.shape and got.flags.c_contiguous
    if sigma < BLUR_MATRIX_FROM:
        assert np.array_equal(got, ref)
    else:
        tol = 1e-14 if dtype == np.float64 else 3e-7
        assert np.abs(got - ref).max() <= tol * np.abs(ref).max()


def test_gaussian_blur_refuses_what_it_does_not_blur():
    from ratouch.images import gaussian_blur

    with pytest.raises(ValueError, match="float"):
        gaussian_blur(np.zeros((4, 4, 3), np.uint8), 2.0)
    with pytest.raises(ValueError, match="2-D or 3-D"):
        gaussian_blur(np.zeros(4), 2.0)
    with pytest.raises(ValueError, match="sigma"):
        gaussian_blur(np.zeros((4, 4)), 0.0)
