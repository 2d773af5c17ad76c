"""Epipolar patches (§3.1.1): coverage, correspondence of strips, orientation."""

import numpy as np
import pytest

from conftest import look_at, project
from pipeline.geometry import epipoles, fundamental_from_cameras
from pipeline.patches import (build_ref_strips, build_support_segments, finite_epipole, iter_covering,
                              patch_coverage, ref_frames)

SIZE = (120, 160)
L = 12


@pytest.mark.parametrize("e_h", [
    np.array([900.0, -300.0, 1.0]),      # outside the image
    np.array([70.0, 50.0, 1.0]),         # inside the image
    np.array([1.0, 0.2, 0.0]),           # at infinity (parallel epipolar lines)
    np.array([-1.0, 1e-9, 1e-12]),       # numerically at infinity
])
def test_each_pixel_is_covered_by_about_nine_patches(e_h):
    st = build_ref_strips(e_h, SIZE, L, along_overlap=3, rows=9, n_fans=3)
    cov = patch_coverage(st, SIZE)
    if st.circle:
        # near the epipole strips shrink to nothing; away from it the count is exact
        e = st.epipole
        yy, xx = np.mgrid[0:SIZE[0], 0:SIZE[1]]
        far = np.hypot(xx - e[0], yy - e[1]) > 2 * L
        cov = cov[far]
    assert np.all(cov == 9), np.unique(cov, return_counts=True)


def test_patch_distances_are_within_the_patch():
    st = build_ref_strips(np.array([900.0, -300.0, 1.0]), SIZE, L, 3, 9, 3)
    for _, ok, d2 in iter_covering(st, SIZE):
        assert np.all(np.sqrt(d2[ok]) <= np.hypot(L / 2, L) + 1e-6)


def test_far_epipole_is_moved_in_but_keeps_direction():
    e = finite_epipole(np.array([1.0, 1.0, 1e-15]), SIZE)
    c = np.array([(SIZE[1] - 1) / 2, (SIZE[0] - 1) / 2])
    assert np.linalg.norm(e - c) > 1e5
    assert np.allclose((e - c) / np.linalg.norm(e - c), np.array([1, 1]) / np.sqrt(2), atol=1e-9)


def _strip_of(st, pts):
    """Strip id of fan 0 containing each reference point, and its along coordinate."""
    d = pts - st.epipole
    theta = np.arctan2(d[:, 1], d[:, 0])
    k = st.strip_index(np.mod(theta - st.theta_lo, 2 * np.pi), 0)
    lut = {int(kk): s for s, (f, kk) in enumerate(zip(st.fan, st.k)) if f == 0}
    return np.array([lut.get(int(kk), -1) for kk in k])


@pytest.mark.parametrize("baseline", ["sideways", "forward"])
def test_static_points_fall_inside_the_corresponding_support_strip(baseline):
    ref = look_at([0, -8, 1.6], [0, 0, 1.0], 500.0, (480, 640), 0.03)
    C_sup = [3, -7.5, 2.2] if baseline == "sideways" else [0.3, -5.0, 1.7]   # forward: epipole in view
    sup = look_at(C_sup, [0.5, 0, 1.0], 560.0, (480, 640), -0.05)
    F = fundamental_from_cameras(ref.P, sup.P)
    e_ref, _ = epipoles(F)
    st = build_ref_strips(e_ref, (480, 640), 24, 3, 9, 3)
    sg = build_support_segments(F, st, (480, 640), (480, 640))
    rng = np.random.default_rng(1)
    X = np.column_stack([rng.uniform(-3, 3, 400), rng.uniform(0, 4, 400), rng.uniform(0, 2.5, 400)])
    xr, xs = project(ref, X), project(sup, X)
    inside = (np.all((xr >= 0) & (xr < [640, 480]), axis=1) & np.all((xs >= 0) & (xs < [640, 480]), axis=1))
    sid = _strip_of(st, xr[inside])
    xs = xs[inside]
    found = 0
    for s, p in zip(sid, xs):
        segs = np.nonzero(sg.strip == s)[0]
        assert len(segs) > 0
        ph = np.array([p[0], p[1], 1.0])
        a, b = sg.bound_a[segs[0]] @ ph, sg.bound_b[segs[0]] @ ph
        found += a * b <= 1e-9            # between the two boundary lines
    assert found == len(xs)


def test_traversal_direction_matches_on_a_visible_plane():
    """Moving outward along a reference strip on the ground plane moves forward along the
    corresponding support segment (the frames have the same handedness, patches.py)."""
    ref = look_at([0, -8, 1.6], [0, 0, 0.5], 500.0, (480, 640), 0.03)
    for C_sup, roll in (([3, -7.5, 2.2], -0.05), ([-4, -6, 3.0], 0.1), ([0.5, -4.0, 1.8], 0.0)):
        sup = look_at(C_sup, [0.5, 0, 0.5], 560.0, (480, 640), roll)
        F = fundamental_from_cameras(ref.P, sup.P)
        e_ref, _ = epipoles(F)
        st = build_ref_strips(e_ref, (480, 640), 24, 3, 9, 3)
        sg = build_support_segments(F, st, (480, 640), (480, 640))
        d_r, _ = ref_frames(st)
        # ground points and a second point 15 px further out along the same reference strip
        rng = np.random.default_rng(2)
        X1 = np.column_stack([rng.uniform(-3, 3, 100), rng.uniform(0, 4, 100), np.zeros(100)])
        x1 = project(ref, X1)
        ok = np.all((x1 >= 0) & (x1 < [640, 480]), axis=1)
        x1, X1 = x1[ok], X1[ok]
        sid = _strip_of(st, x1)
        x2 = x1 + 15 * d_r[sid]
        # back-project x2 onto the ground plane z = 0
        rays = np.column_stack([x2, np.ones(len(x2))]) @ np.linalg.inv(ref.K).T @ ref.R
        X2 = ref.C + rays * (-ref.C[2] / rays[:, 2:3])
        y1, y2 = project(sup, X1), project(sup, X2)
        agree = []
        for s, a, b in zip(sid, y1, y2):
            # the segment holding y1 (a strip through the support epipole has two halves)
            for g in np.nonzero(sg.strip == s)[0]:
                s_a = (a - sg.foot[g]) @ sg.d[g]
                ends = sorted([sg.s0[g], sg.s0[g] + sg.step[g] * (sg.length[g] - 1)])
                if ends[0] - 1 <= s_a <= ends[1] + 1:
                    agree.append((b - a) @ sg.along_dir[g] > 0)
        assert len(agree) > 30
        assert np.mean(agree) > 0.97


@pytest.mark.parametrize("baseline", ["sideways", "forward"])
def test_the_compiled_support_samples_equal_their_numpy_definition(baseline):
    """support_sample_points (compiled) gives numpy's samples bit for bit: sample i of segment g on
    the central line at s0 + step (i - offset), row r where the normal through it meets row line r
    (forward: the epipole is in view and strips split into two segments)."""
    from pipeline.patches import support_sample_points
    ref = look_at([0, -8, 1.6], [0, 0, 1.0], 500.0, (480, 640), 0.03)
    C_sup = [3, -7.5, 2.2] if baseline == "sideways" else [0.3, -5.0, 1.7]
    sup = look_at(C_sup, [0.5, 0, 1.0], 560.0, (480, 640), -0.05)
    F = fundamental_from_cameras(ref.P, sup.P)
    st = build_ref_strips(epipoles(F)[0], (480, 640), 24, 3, 9, 3)
    sg = build_support_segments(F, st, (480, 640), (480, 640))
    seg = np.repeat(np.arange(len(sg.strip)), sg.length)
    s = sg.s0[seg] + sg.step[seg] * (np.arange(len(seg)) - sg.offset[seg])
    base = sg.foot[seg] + s[:, None] * sg.d[seg]                              # (N, 2)
    lines = sg.row_lines[seg]                                                 # (N, rows, 3)
    num = lines[..., 0] * base[:, None, 0] + lines[..., 1] * base[:, None, 1] + lines[..., 2]
    den = lines[..., 0] * sg.n[seg][:, None, 0] + lines[..., 1] * sg.n[seg][:, None, 1]
    u = -num / np.where(np.abs(den) < 1e-12, 1e-12, den)                      # (N, rows)
    want = base[None] + u.T[..., None] * sg.n[seg][None]
    xy, got_seg = support_sample_points(sg)
    assert len(seg) > 1000 and xy.shape == want.shape
    assert np.array_equal(got_seg, seg) and np.array_equal(xy, want)
