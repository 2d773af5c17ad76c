"""Descriptor similarity properties (§3.1.2)."""

import numpy as np

from pipeline.descriptors import (color_similarity, hog_similarity, image_channels, strip_features,
                                  window_descriptors)


def _strip_of_image(rgb, rows=9):
    """Sample an image row-block as one strip: along = +x, across = +y."""
    h, w = rgb.shape[:2]
    ys = np.linspace(2, h - 3, rows)
    xy = np.stack(np.meshgrid(np.arange(w, dtype=float), ys), axis=-1)        # (rows, w, 2)
    ch = image_channels(rgb, 10)
    along = np.tile([[1.0, 0.0]], (w, 1))
    across = np.tile([[0.0, 1.0]], (w, 1))
    return strip_features(ch, xy, along, across, 3, 9, 10)


def _textured(seed, h=40, w=200):
    rng = np.random.default_rng(seed)
    img = (rng.random((h // 4, w // 4, 3)) * 255).astype(np.uint8)
    import cv2
    return cv2.resize(img, (w, h), interpolation=cv2.INTER_CUBIC)


def test_identical_windows_have_similarity_one():
    sf = _strip_of_image(_textured(0))
    wd = window_descriptors(sf, np.array([10, 10, 50]), np.array([24, 24, 24]), 3, 0.05)
    assert np.isclose(hog_similarity(wd.hog[:1], wd.hog[1:2])[0, 0], 1.0, atol=1e-5)
    assert np.isclose(color_similarity(wd.color[:1], wd.color[1:2])[0, 0], 1.0, atol=1e-6)


def test_similarities_are_symmetric_and_bounded():
    sf = _strip_of_image(_textured(1))
    wd = window_descriptors(sf, np.arange(0, 150, 7), np.full(22, 24), 3, 0.05)
    h = hog_similarity(wd.hog, wd.hog)
    c = color_similarity(wd.color, wd.color)
    for m in (h, c):
        assert np.allclose(m, m.T, atol=1e-6)
        assert m.min() >= -1e-6 and m.max() <= 1 + 1e-6
        assert np.allclose(np.diag(m), 1.0, atol=1e-5)


def test_same_content_elsewhere_matches_better_than_other_content():
    """A patch copied further along the strip is found again; other texture scores lower."""
    img = _textured(2)
    img[:, 150:174] = img[:, 20:44]
    sf = _strip_of_image(img)
    ref = window_descriptors(sf, np.array([20]), np.array([24]), 3, 0.05)
    cands = window_descriptors(sf, np.arange(60, 176, 2), np.full(58, 24), 3, 0.05)
    sim = hog_similarity(ref.hog, cands.hog)[0]
    assert np.arange(60, 176, 2)[np.argmax(sim)] == 150
    assert sim.max() > 0.9 and np.median(sim) < 0.75     # the copy's borders add two edges


def test_disjoint_colour_histograms_have_zero_iou():
    a = np.zeros((1, 100), np.float32); a[0, 5] = 1
    b = np.zeros((1, 100), np.float32); b[0, 77] = 1
    assert color_similarity(a, b)[0, 0] == 0
    half = np.zeros((1, 100), np.float32); half[0, 5] = half[0, 77] = 0.5
    assert np.isclose(color_similarity(a, half)[0, 0], 0.5 / 1.5)


def test_flat_patches_match_each_other():
    """With the flat prior, two uniform patches are similar (uniform background is ambiguous)."""
    img = np.full((40, 200, 3), 120, np.uint8)
    sf = _strip_of_image(img)
    wd = window_descriptors(sf, np.array([10, 100]), np.array([24, 36]), 3, 0.05)
    assert hog_similarity(wd.hog[:1], wd.hog[1:])[0, 0] > 0.99


def test_hog_follows_the_strip_frame():
    """Vertical stripes seen along +x equal horizontal stripes seen along +y."""
    x = np.arange(200)
    vert = np.repeat(((np.sin(x / 3.0) > 0) * 200 + 20).astype(np.uint8)[None, :, None], 40, 0).repeat(3, 2)
    sf_v = _strip_of_image(vert)
    ch = image_channels(np.ascontiguousarray(vert.transpose(1, 0, 2)), 10)
    ys = np.linspace(2, 37, 9)
    xy = np.stack(np.meshgrid(np.arange(200, dtype=float), ys), axis=-1)[..., ::-1].copy()   # along +y
    sf_h = strip_features(ch, xy, np.tile([[0.0, 1.0]], (200, 1)), np.tile([[-1.0, 0.0]], (200, 1)), 3, 9, 10)
    a = window_descriptors(sf_v, np.array([50]), np.array([24]), 3).hog
    b = window_descriptors(sf_h, np.array([50]), np.array([24]), 3).hog
    assert hog_similarity(a, b)[0, 0] > 0.95


def test_smoothed_hue_histogram_keeps_mass_and_wraps_around():
    from pipeline.descriptors import smooth_hist
    h = np.zeros((2, 100), np.float32)
    h[0, 9 * 10 + 3] = 1.0          # last hue bin: its neighbours are hue 8 and (wrapping) hue 0
    h[1, 4 * 10 + 0] = 1.0
    s = smooth_hist(h)
    assert np.allclose(s.sum(axis=1), 1.0)
    assert np.isclose(s[0, 0 * 10 + 3], 0.25) and np.isclose(s[0, 8 * 10 + 3], 0.25)
    assert np.isclose(s[1, 4 * 10 + 0], 0.5)             # saturation stays hard
    # a one-bin hue shift empties the hard intersection but not the smoothed one
    a, b = np.zeros((1, 100), np.float32), np.zeros((1, 100), np.float32)
    a[0, 9 * 10 + 3], b[0, 0 * 10 + 3] = 1.0, 1.0
    assert color_similarity(a, b)[0, 0] == 0.0
    assert color_similarity(smooth_hist(a), smooth_hist(b))[0, 0] > 0.3


def test_achromatic_pixels_share_one_bin_whatever_their_hue():
    grey_pink = np.array([[[200, 196, 197]]], np.uint8)      # hue near 180 (wraps), low saturation
    grey_green = np.array([[[196, 200, 197]]], np.uint8)
    dark_red = np.array([[[20, 2, 2]]], np.uint8)
    red = np.array([[[220, 30, 30]]], np.uint8)
    bins = lambda img, on: int(image_channels(img, 10, achromatic=on).color_bin[0, 0])
    assert bins(grey_pink, False) != bins(grey_green, False)
    assert bins(grey_pink, True) == bins(grey_green, True) == bins(dark_red, True) == 0
    assert bins(red, True) == bins(red, False) != 0


def test_window_descriptors_compiled_equal_their_numpy_definition():
    """Every window width, position, the hog floor and the hue smoothing on or off: the compiled
    pass gives numpy's values to float32's last bits (its norms and sums add in float64)."""
    from pipeline.descriptors import window_descriptors_numpy
    sf = _strip_of_image(_textured(7))
    rng = np.random.default_rng(2)
    length = rng.integers(6, 60, 400)
    start = rng.integers(0, 200 - length + 1)
    start[:3], length[:3] = [0, 0, 200 - 7], [200, 1, 7]                # the whole strip, one sample, the end
    for floor, smooth in ((0.0, False), (0.05, True), (0.05, False)):
        a = window_descriptors(sf, start, length, 3, floor, smooth)
        b = window_descriptors_numpy(sf, start, length, 3, floor, smooth)
        for name in ("hog", "color", "valid"):
            x, y = getattr(a, name), getattr(b, name)
            assert x.dtype == y.dtype == np.float32 and x.shape == y.shape
            np.testing.assert_allclose(x, y, rtol=2e-6, atol=2e-7, err_msg=name)
    empty = window_descriptors(sf, np.zeros(0, np.int64), np.zeros(0, np.int64), 3, 0.05, True)
    assert empty.hog.shape == (0, 81) and empty.color.shape == (0, 100)


def test_strip_sums_compiled_equal_their_numpy_definition():
    """The compiled strip pass (its orientation from atan's series, not libm's atan2) gives the
    numpy definition's sums: colour and valid counts exactly, the HOG cells to float32's last bits,
    also for gradients on the bins' edges, along the axes, zero and negative zero."""
    from pipeline.descriptors import _strip_kernel, strip_sums_numpy
    rng = np.random.default_rng(5)
    rows, n, bins, nb = 24, 400, 9, 100
    gx = rng.normal(0, 40, (rows, n)).astype(np.float32)
    gy = rng.normal(0, 40, (rows, n)).astype(np.float32)
    edges = np.pi * (np.arange(2 * bins) + 0.5) / bins                # bin edges (centres at integers - 0.5)
    gx[0, :2 * bins], gy[0, :2 * bins] = 50 * np.cos(edges), 50 * np.sin(edges)
    gx[1, :8] = [0, -0.0, 5, -5, 0, 0, 3, -3]
    gy[1, :8] = [0, 0, 0, -0.0, 5, -5, 3, 3]
    theta = rng.uniform(0, 2 * np.pi, n)
    theta[:2 * bins] = 0.0                                            # strip frame = image frame there
    along = np.stack([np.cos(theta), np.sin(theta)], 1)
    across = np.stack([-np.sin(theta), np.cos(theta)], 1)
    valid = rng.random((rows, n)) > 0.1
    valid[:2] = True
    cb = rng.integers(0, nb, (rows, n)).astype(np.uint8)
    cell_of_row = ((np.arange(rows) * 3) // rows).astype(np.int64)
    got = _strip_kernel(gx, gy, cb, valid, along, across, cell_of_row, 3, bins, nb)
    want = strip_sums_numpy(gx, gy, cb, valid, along, across, cell_of_row, 3, bins, nb)
    np.testing.assert_array_equal(got[1], want[1])
    np.testing.assert_array_equal(got[2], want[2])
    np.testing.assert_allclose(got[0], want[0], rtol=1e-6, atol=1e-3)   # sums up to ~1e5
    # sample by sample, the two bins' shares within 1.5e-7 of the magnitude (a series one term
    # shorter, off by 1.3e-7 rad, puts them 3.7e-7 off)
    zero, one_row, first = np.zeros((1, 1), np.uint8), np.ones((1, 1), bool), np.zeros(1, np.int64)
    frame = (np.array([[1.0, 0.0]]), np.array([[0.0, 1.0]]))
    for x, y in zip(gx[:2].ravel(), gy[:2].ravel()):
        args = (np.full((1, 1), x, np.float32), np.full((1, 1), y, np.float32), zero, one_row, *frame, first, 1,
                bins, nb)
        a, b = _strip_kernel(*args)[0][0, 1], strip_sums_numpy(*args)[0][0, 1]
        assert np.abs(a - b).max() <= 1.5e-7 * np.hypot(x, y) + 1e-30, (x, y, a, b)
    # one gradient on a bin's centre goes to that bin alone
    one = _strip_kernel(np.full((1, 1), 10.0, np.float32), np.zeros((1, 1), np.float32), np.zeros((1, 1), np.uint8),
                        np.ones((1, 1), bool), np.array([[np.cos(np.pi / 18), np.sin(np.pi / 18)]]),
                        np.array([[-np.sin(np.pi / 18), np.cos(np.pi / 18)]]), np.zeros(1, np.int64), 1, bins, nb)
    assert np.isclose(one[0][0, 1].max(), 10.0, rtol=1e-6) and np.isclose(one[0][0, 1].sum(), 10.0, rtol=1e-6)
