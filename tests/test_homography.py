"""Homography pairs (default preset): classification and point-to-point matching after alignment."""

import cv2
import numpy as np

from pipeline.features import detect
from pipeline.homography import match_pair_homography
from pipeline.params import get_preset
from pipeline.support import HOMOGRAPHY, REJECTED, estimate_pair


def _scene(seed=0, h=240, w=320):
    rng = np.random.default_rng(seed)
    img = cv2.resize((rng.random((h // 8, w // 8, 3)) * 255).astype(np.uint8), (w, h), interpolation=cv2.INTER_CUBIC)
    for _ in range(40):
        cv2.circle(img, tuple(int(v) for v in rng.integers(0, [w, h])), int(rng.integers(4, 20)),
                   rng.integers(0, 255, 3).tolist(), -1)
    return img


def _rotated_view(img, H):
    return cv2.warpPerspective(img, H, (img.shape[1], img.shape[0]), borderMode=cv2.BORDER_REFLECT)


H_TRUE = np.array([[0.98, 0.05, 6.0], [-0.04, 1.01, -4.0], [1e-5, -2e-5, 1.0]])


def test_same_spot_pair_is_a_homography_pair_in_default_and_rejected_in_paper():
    a = _scene()
    b = _rotated_view(a, H_TRUE)
    fa, fb = detect(a, 4000, 0.02), detect(b, 4000, 0.02)
    paper = estimate_pair(0, 1, fa, fb, a.shape[:2], b.shape[:2], get_preset("paper").geometry)
    ours = estimate_pair(0, 1, fa, fb, a.shape[:2], b.shape[:2], get_preset("default").geometry)
    assert paper.status == REJECTED and "homography" in paper.reason
    assert ours.status == HOMOGRAPHY and ours.H is not None
    # x_sup ~ H x_ref: check on a few points
    pts = np.array([[50.0, 60.0], [250.0, 200.0]])
    ph = np.column_stack([pts, np.ones(2)]) @ ours.H.T
    true = np.column_stack([pts, np.ones(2)]) @ H_TRUE.T
    assert np.allclose(ph[:, :2] / ph[:, 2:], true[:, :2] / true[:, 2:], atol=1.5)
    back = ours.reversed()
    assert np.allclose(back.H @ ours.H / (back.H @ ours.H)[2, 2], np.eye(3), atol=1e-6)


def test_a_pasted_object_has_low_confidence_and_the_rest_high():
    params = get_preset("default").replace(max_side=320)
    a = _scene(1)
    b = _rotated_view(a, H_TRUE)
    b = b.copy()
    cv2.rectangle(b, (150, 100), (200, 150), (20, 220, 30), -1)     # something new in the support
    r = match_pair_homography(0, 1, a, b, H_TRUE, params)
    assert r.kind == "homography"
    # where the object appears in reference coordinates (inverse map of the rectangle's centre)
    c = np.linalg.inv(H_TRUE) @ np.array([175.0, 125.0, 1.0])
    cx, cy = (c[:2] / c[2]).round().astype(int)
    obj = r.hog_map[cy - 8:cy + 8, cx - 8:cx + 8]
    rest = r.hog_map[20:80, 20:100]
    assert np.nanmean(obj) < np.nanmean(rest) - 0.2
    assert r.evidence[60, 60] > 0.99


def test_out_of_view_has_no_evidence():
    params = get_preset("default").replace(max_side=320)
    a = _scene(2)
    shift = np.array([[1.0, 0, 120.0], [0, 1.0, 0], [0, 0, 1.0]])   # support sees only part of a
    b = _rotated_view(a, shift)
    r = match_pair_homography(0, 1, a, b, shift, params)
    # reference pixels x with x + 120 beyond the support's width are out of view
    assert r.evidence[:, 300:].mean() < 0.05 and r.evidence[:, :150].mean() > 0.95


def test_homography_is_trusted_only_within_reach_of_its_inliers():
    """Where no inlier confirms H (a plane seen from apart: the rest of the scene has parallax),
    the pair gives no evidence instead of reading the misalignment as motion."""
    params = get_preset("default").replace(max_side=320)
    a = _scene(3)
    b = _rotated_view(a, H_TRUE)
    top_only = np.stack(np.meshgrid(np.arange(10, 310, 15.0), np.arange(5, 60, 15.0)), -1).reshape(-1, 2)
    r = match_pair_homography(0, 1, a, b, H_TRUE, params, top_only)
    reach = params.patches.homography_reach_frac * 320
    everywhere = match_pair_homography(0, 1, a, b, H_TRUE, params)
    far = slice(int(60 + reach) + 20, None)
    assert np.allclose(r.evidence[:60], everywhere.evidence[:60], atol=1e-6)
    assert r.evidence[far].max() == 0.0 and everywhere.evidence[far].mean() > 0.9
