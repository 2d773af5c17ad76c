"""Known-answer geometry on a synthetic camera pair."""

import numpy as np
import pytest

from conftest import project
from pipeline.geometry import (epipolar_lines, epipoles, fundamental_to_original, scale_matrix,
                               symmetric_epipolar_distance)


def test_true_correspondences_satisfy_F(camera_pair):
    ref, sup, F, X = camera_pair
    xr, xs = project(ref, X), project(sup, X)
    assert np.max(symmetric_epipolar_distance(F, xr, xs)) < 1e-6


def test_epipoles_are_the_other_camera_centres(camera_pair):
    ref, sup, F, _ = camera_pair
    e_ref, e_sup = epipoles(F)
    assert np.allclose(F @ e_ref, 0, atol=1e-10) and np.allclose(F.T @ e_sup, 0, atol=1e-10)
    expect_ref = project(ref, sup.C[None])[0]       # the support camera seen from the reference
    expect_sup = project(sup, ref.C[None])[0]
    assert np.allclose(e_ref[:2] / e_ref[2], expect_ref, atol=1e-6)
    assert np.allclose(e_sup[:2] / e_sup[2], expect_sup, atol=1e-6)


def test_epipolar_lines_pass_through_matches_and_epipole(camera_pair):
    ref, sup, F, X = camera_pair
    xr, xs = project(ref, X), project(sup, X)
    lines = epipolar_lines(F, xr)
    assert np.allclose(np.linalg.norm(lines[:, :2], axis=1), 1.0)
    assert np.max(np.abs(np.sum(lines * np.column_stack([xs, np.ones(len(xs))]), axis=1))) < 1e-6
    _, e_sup = epipoles(F)
    assert np.max(np.abs(lines @ e_sup)) < 1e-9


def test_a_wrong_point_is_far_from_its_line(camera_pair):
    ref, sup, F, X = camera_pair
    xr, xs = project(ref, X), project(sup, X)
    d = symmetric_epipolar_distance(F, xr, xs[::-1])
    assert np.median(d) > 10


def test_fundamental_to_original_resolution(camera_pair):
    """F fitted at working resolution maps to the convention at original resolution."""
    ref, sup, F_orig, X = camera_pair
    xr, xs = project(ref, X), project(sup, X)
    s_r, s_s = 0.5, 0.25
    to_work = lambda x, s: (np.column_stack([x, np.ones(len(x))]) @ scale_matrix(s).T)[:, :2]
    # F in working coordinates: x_s_w^T F_w x_r_w = 0
    F_work = np.linalg.inv(scale_matrix(s_s)).T @ F_orig @ np.linalg.inv(scale_matrix(s_r))
    assert np.max(symmetric_epipolar_distance(F_work, to_work(xr, s_r), to_work(xs, s_s))) < 1e-6
    back = fundamental_to_original(F_work, s_r, s_s)
    assert np.max(symmetric_epipolar_distance(back, xr, xs)) < 1e-6


def test_triplet_check_rejects_a_pair_fooled_by_repetition():
    """Four cameras see the same points; pair (0, 1) matched every point to a copy one 'period'
    away (as repeated texture does) and fitted an F to that. Three views expose it."""
    import cv2

    from conftest import look_at
    from pipeline.geometry import fundamental_from_cameras
    from pipeline.support import OK, REJECTED, PairGeometry, triplet_check

    cams = [look_at([x, -8, 1.6 + 0.3 * k], [0, 0, 1.0], 500.0, (480, 640), 0.02 * k)
            for k, x in enumerate([-3.0, -1.0, 1.0, 3.0])]
    rng = np.random.default_rng(0)
    X = np.column_stack([rng.uniform(-4, 4, 300), rng.uniform(-1, 5, 300), rng.uniform(0, 3, 300)])
    xs = [project(c, X).astype(np.float32) for c in cams]
    pairs = {}
    for i in range(4):
        for j in range(i + 1, 4):
            a, b = xs[i], xs[j]
            F = fundamental_from_cameras(cams[i].P, cams[j].P)
            if (i, j) == (0, 1):
                shifted = project(cams[1], X + np.array([0.8, 0.0, 0.0])).astype(np.float32)
                b = shifted
                F, _ = cv2.findFundamentalMat(a, b, cv2.FM_8POINT)
            empty = np.zeros((0, 2), np.float32)
            g = PairGeometry(i, j, F, OK, "", 300, 300, 0.5, 0.5, 0.1, 1.0, a, b, empty, empty, source="two-view")
            pairs[(i, j)], pairs[(j, i)] = g, g.reversed()
    out = triplet_check(pairs, 4, 4.0)
    assert out[(0, 1)].status == REJECTED and "triplets disagree" in out[(0, 1)].reason
    assert out[(1, 0)].status == REJECTED
    assert all(out[(i, j)].status == OK for i in range(4) for j in range(4) if i != j and {i, j} != {0, 1})


def test_degenerate_samples_give_no_model_not_an_error():
    """OpenCV's USAC asserts on some degenerate samples; the pair is then rejected, never a crash."""
    from pipeline.support import _fit_f, fit_homography
    x = np.linspace(0, 100, 30, dtype=np.float32)
    line = np.column_stack([x, 2 * x + 1]).astype(np.float32)
    same = np.repeat(np.array([[5.0, 5.0]], np.float32), 30, axis=0)
    for a, b in ((line, line), (same, same), (line, same)):
        F, mask = _fit_f(a, b, 1.5)
        assert F is None or F.shape == (3, 3)
        H, hmask = fit_homography(a, b, 3.0)
        assert H is None or H.shape == (3, 3)


def test_cap_supports_picks_k_deterministically_and_spreads_viewpoints():
    """The cap keeps k supports: the best matched first, then those that see from elsewhere."""
    from pipeline.support import OK, PairGeometry, cap_supports
    empty = np.zeros((0, 2), np.float32)
    n = 7
    centres = np.array([[0, 0, 0], [1, 0, 0], [1.05, 0, 0], [1.1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0.0]])
    inliers = {1: 900, 2: 880, 3: 870, 4: 300, 5: 290, 6: 280}
    pairs = {}
    for j in range(1, n):
        pairs[(0, j)] = PairGeometry(0, j, np.eye(3), OK, "", inliers[j], inliers[j], 0.5, 0.1, 0.1, 1.0,
                                     empty, empty, empty, empty, source="reconstruction", uncertainty_px=1.0)
    supports = [list(range(1, n))] + [[] for _ in range(n - 1)]
    a = cap_supports(supports, pairs, 3, centres)
    assert a == cap_supports(supports, pairs, 3, centres)          # deterministic
    assert len(a[0]) == 3 and 1 in a[0]
    assert len({2, 3} & set(a[0])) == 0          # near-duplicates of the first viewpoint lose to other directions
    b = cap_supports(supports, pairs, 3, None)                     # without cameras: the best matched
    assert b[0] == [1, 2, 3]
    assert cap_supports(supports, pairs, 10, centres)[0] == supports[0]


def test_uncertainty_gate_rejects_only_uncertain_two_view_pairs():
    """Two-view F's whose half-data refits disagree by more than the limit are not trusted;
    reconstruction and homography pairs, and certain two-view pairs, stay as they were."""
    from pipeline.support import HOMOGRAPHY, OK, REJECTED, PairGeometry, uncertainty_gate
    empty = np.zeros((0, 2), np.float32)

    def pair(i, j, status, source, unc):
        g = PairGeometry(i, j, np.eye(3), status, "", 100, 100, 0.5, 0.1, 0.1, 1.0, empty, empty, empty, empty,
                         source=source, uncertainty_px=unc)
        return {(i, j): g, (j, i): g.reversed()}
    pairs = {**pair(0, 1, OK, "two-view", 5.0), **pair(0, 2, OK, "two-view", 30.0),
             **pair(1, 2, OK, "reconstruction", 30.0), **pair(0, 3, HOMOGRAPHY, "homography", 30.0),
             **pair(1, 3, OK, "two-view", float("nan"))}
    out = uncertainty_gate(pairs, 16.0)
    assert out[(0, 2)].status == out[(2, 0)].status == REJECTED and "too uncertain (30.0 px" in out[(0, 2)].reason
    assert out[(1, 3)].status == REJECTED                     # unknown is not certain
    for ij in ((0, 1), (1, 0), (1, 2), (2, 1), (0, 3), (3, 0)):
        assert out[ij] is pairs[ij]
    assert uncertainty_gate(pairs, 0.0) is pairs               # off


def test_the_fast_triplet_closing_equals_the_one_by_position():
    """_chained finds the shared reference keypoints by their exact positions (a sorted search),
    as a dictionary of positions does, the last row winning where a position repeats."""
    from pipeline.geometry import symmetric_epipolar_distance
    from pipeline.support import OK, PairGeometry, _chained
    rng = np.random.default_rng(4)
    empty = np.zeros((0, 2), np.float32)
    pts = rng.uniform(0, 500, (60, 2)).astype(np.float32)
    a_rows = np.concatenate([pts[:40], pts[5:6]])                 # a repeated position in (0, 1)
    b_rows = pts[rng.permutation(60)[:45]]
    F = rng.normal(size=(3, 3))
    sup1 = rng.uniform(0, 500, (len(a_rows), 2)).astype(np.float32)
    sup2 = rng.uniform(0, 500, (len(b_rows), 2)).astype(np.float32)
    g = lambda i, j, r, s, FF=np.eye(3): PairGeometry(i, j, FF, OK, "", 50, 50, 0.5, 0.1, 0.1, 1.0, r, s, empty, empty)
    pairs = {(0, 1): g(0, 1, a_rows, sup1), (0, 2): g(0, 2, b_rows, sup2), (1, 2): g(1, 2, empty, empty, F)}
    index = {row.tobytes(): n for n, row in enumerate(a_rows)}
    a = [index[row.tobytes()] for row in b_rows if row.tobytes() in index]
    b = [n for n, row in enumerate(b_rows) if row.tobytes() in index]
    want = float(np.median(symmetric_epipolar_distance(F, sup1[a], sup2[b])))
    assert _chained(pairs, 0, 1, 2) == pytest.approx(want, abs=1e-9)
    assert _chained(pairs, 0, 1, 2, min_tracks=len(a) + 1) is None


def test_lines_are_clipped_to_the_image_border_to_border():
    """clip_lines: each segment's ends lie on its line and on the image's border, as far apart as
    the line's crossings allow; a line that misses the image is not in view."""
    from pipeline.geometry import clip_line, clip_lines
    h, w = 480, 640
    rng = np.random.default_rng(3)
    lines = rng.normal(size=(500, 3)) * [1.0, 1.0, 300.0]
    lines = np.vstack([lines, [[1, 0, -10], [0, 1, -20], [1, -1, 0], [0, 0, 1], [1, 0, 700]]])   # vertical,
    seg, ok = clip_lines(lines, (h, w))                          # horizontal, a corner, none, beside the image
    assert not ok[-1] and not ok[-2] and ok[-5] and ok[-4] and ok[-3]
    for l, s, o in zip(lines, seg, ok):
        if not np.any(l[:2]):                                   # the line at infinity
            assert not o
            continue
        unit = l / np.hypot(l[0], l[1])
        ts = np.linspace(-2000, 2000, 40001)                    # the line, densely: its part inside the image
        p0 = -unit[2] * unit[:2]
        pts = p0[None] + ts[:, None] * np.array([-unit[1], unit[0]])[None]
        inside = (pts[:, 0] >= 0) & (pts[:, 0] <= w - 1) & (pts[:, 1] >= 0) & (pts[:, 1] <= h - 1)
        if not o:
            assert inside.sum() <= 1
            assert clip_line(l, (h, w)) is None
            continue
        assert np.all(np.abs(s @ unit[:2] + unit[2]) < 1e-3)                     # on the line
        assert np.all((s >= -1e-3) & (s <= [w - 1 + 1e-3, h - 1 + 1e-3]))        # in the image
        on_border = np.minimum.reduce([s[:, 0], w - 1 - s[:, 0], s[:, 1], h - 1 - s[:, 1]])
        assert np.all(on_border < 1e-3)                                           # at its border
        assert np.linalg.norm(s[1] - s[0]) >= np.ptp(ts[inside]) - 0.2          # the whole of the inside part
        np.testing.assert_array_equal(clip_line(l, (h, w)), s)
