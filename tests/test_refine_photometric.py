"""Spatial refinement (guided filter) and photometric normalisation (default preset)."""

import numpy as np

from pipeline.photometric import apply_gain_offset, fit_gain_offset, normalise_aligned
from pipeline.refine import guided_filter, refine


def test_guided_filter_keeps_constants_and_removes_speckle():
    guide = np.full((60, 80), 0.5, np.float32)
    const = np.full((60, 80), 0.3, np.float32)
    assert np.allclose(guided_filter(guide, const, 5, 0.01), 0.3, atol=1e-5)
    speckle = const.copy()
    speckle[30, 40] = 1.0                       # one isolated pixel on a flat photo
    out = guided_filter(guide, speckle, 5, 0.01)
    assert out[30, 40] < 0.32


def test_guided_filter_keeps_edges_of_the_photo():
    guide = np.zeros((60, 80), np.float32)
    guide[:, 40:] = 1.0                          # an edge in the photo
    src = np.where(guide > 0, 0.9, 0.1).astype(np.float32)
    out = guided_filter(guide, src, 6, 1e-4)
    assert out[:, :35].max() < 0.15 and out[:, 45:].min() > 0.85


def test_refine_output_range():
    rng = np.random.default_rng(1)
    rgb = (rng.random((40, 50, 3)) * 255).astype(np.uint8)
    out = refine(rng.random((40, 50)).astype(np.float32), rgb, 4, 0.01)
    assert out.shape == (40, 50) and out.min() >= 0 and out.max() <= 1


def test_refine_makes_no_new_extremes():
    # "no evidence" (0.5) beside static evidence (0.1), the photo dark, then a bright line and grey
    # just past the step: the plain guided filter overshoots past 0.5 there (0.58); refine must not
    rgb = np.zeros((60, 80, 3), np.uint8)
    rgb[:, 41] = 255
    rgb[:, 42:] = 128
    dyn = np.full((60, 80), 0.1, np.float32)
    dyn[:, 40:] = 0.5
    gray = rgb[..., 0].astype(np.float32) / 255.0
    assert guided_filter(gray, dyn, 6, 0.01).max() > 0.55         # the overshoot this guards against
    out = refine(dyn, rgb, 6, 0.01)
    assert out.max() <= 0.5 and out.min() >= 0.1
    assert np.all(out[:, 55:] == 0.5)                              # far from the step: untouched
    spot = np.full((60, 80), 0.2, np.float32)
    spot[28:33, 38:43] = 0.9                                       # a mover is smoothed, not widened
    out = refine(spot, rgb, 4, 0.01)
    assert np.all(out[:, :30] == 0.2) and out.max() <= 0.9


def test_gain_offset_is_recovered_despite_outliers():
    rng = np.random.default_rng(2)
    ref = rng.uniform(20, 230, (500, 3))
    a_true, b_true = np.array([1.2, 0.9, 1.05]), np.array([-10.0, 5.0, 0.0])
    sup = (ref - b_true) / a_true
    sup[:60] = rng.uniform(0, 255, (60, 3))      # 12 % of the samples are not shared colours
    a, b = fit_gain_offset(ref, sup)
    assert np.allclose(a, a_true, atol=0.02) and np.allclose(b, b_true, atol=2.0)


def test_aligned_normalisation_maps_support_colours_to_the_reference():
    rng = np.random.default_rng(3)
    ref = (rng.uniform(30, 220, (40, 60, 3))).astype(np.uint8)
    sup = apply_gain_offset(ref, np.array([0.8, 1.1, 0.95]), np.array([10.0, -5.0, 3.0]))
    out = normalise_aligned(ref, sup, np.ones((40, 60), np.uint8), step=1)
    assert np.abs(out.astype(int) - ref.astype(int)).mean() < 1.5


def test_gain_and_offset_by_table_equal_the_per_pixel_arithmetic():
    """apply_gain_offset's 256-value tables give the bytes of a * rgb + b computed per pixel in
    float32, rounded and clipped (gains and offsets as fit_gain_offset clips them)."""
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (37, 53, 3), dtype=np.uint8)
    for _ in range(50):
        a, b = rng.uniform(0.5, 2.0, 3), rng.uniform(-64, 64, 3)
        want = np.clip(rgb.astype(np.float32) * a.astype(np.float32) + b.astype(np.float32) + 0.5, 0, 255)
        assert np.array_equal(apply_gain_offset(rgb, a, b), want.astype(np.uint8))
