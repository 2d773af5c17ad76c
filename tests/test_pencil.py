"""A plane sweep without cameras (pipeline/pencil.py): the pencil of homographies compatible with
F (HZ 13.2), its parameter as an inverse depth, supports aligned on shared tracks, and the sweep
it gives on images (a mover has no hypothesis that all supports agree on)."""

import numpy as np
import pytest

from conftest import look_at, project
from pipeline import pencil as PC
from pipeline.geometry import epipolar_lines, fundamental_from_cameras
from pipeline.params import SweepParams

SIZE = (480, 640)


@pytest.fixture(scope="module")
def three_views():
    """A reference and two supports around a scene 6-14 m deep; the points every view sees."""
    ref = look_at([0, -9, 1.6], [0, 0, 1.0], 520.0, SIZE, 0.02)
    sup_a = look_at([2.5, -8.5, 2.0], [0.4, 0, 1.0], 600.0, SIZE, -0.04)
    sup_b = look_at([-2.0, -8.8, 1.2], [-0.3, 0, 1.2], 470.0, SIZE, 0.03)
    rng = np.random.default_rng(3)
    X = np.column_stack([rng.uniform(-4, 4, 300), rng.uniform(-3, 5, 300), rng.uniform(0, 3.5, 300)])
    return ref, sup_a, sup_b, X


def test_the_pencil_moves_a_pixel_along_its_epipolar_line_through_its_match(three_views):
    ref, sup, _, X = three_views
    F = fundamental_from_cameras(ref.P, sup.P)
    x, x_s = project(ref, X), project(sup, X)
    H0, e, s = PC.two_view_pencil(F, x, x_s)
    assert np.abs(PC.transfer(H0, e, x, s) - x_s).max() < 1e-6        # each match at its own s
    lines = epipolar_lines(F, x)
    for s_any in (-5.0, 0.0, 0.3, 7.0):                                 # any s stays on the line
        q = PC.transfer(H0, e, x, np.full(len(x), s_any))
        dist = np.abs(np.sum(np.column_stack([q, np.ones(len(q))]) * lines, axis=1))
        assert np.nanmax(dist) < 1e-6


def test_the_pencil_parameter_is_an_inverse_depth_up_to_scale_and_a_pixel_affine_offset(three_views):
    """s = k (rho - v . x) (the module's docstring): affine in 1 / z and in the pixel, exactly."""
    ref, sup, _, X = three_views
    F = fundamental_from_cameras(ref.P, sup.P)
    x = project(ref, X)
    _, _, s = PC.two_view_pencil(F, x, project(sup, X))
    z = (X - ref.C) @ ref.R.T @ np.array([0, 0, 1.0])
    A = np.column_stack([1.0 / z, x, np.ones(len(x))])
    fit = np.linalg.lstsq(A, s, rcond=None)[0]
    assert np.abs(A @ fit - s).max() < 1e-9 * np.abs(s).max()
    assert abs(np.corrcoef(A @ fit - fit[1] * x[:, 0] - fit[2] * x[:, 1], 1.0 / z)[0, 1]) > 0.999


def pairs_of(three_views, ids_b=None):
    ref, sup_a, sup_b, X = three_views
    x = project(ref, X)
    ids = np.arange(len(X))
    return {1: (fundamental_from_cameras(ref.P, sup_a.P), x, project(sup_a, X), ids),
            2: (fundamental_from_cameras(ref.P, sup_b.P), x, project(sup_b, X), ids if ids_b is None else ids_b)}


def test_supports_aligned_on_their_tracks_share_one_hypothesis_per_point(three_views):
    ref, sup_a, sup_b, X = three_views
    pc = PC.shared_pencil(pairs_of(three_views), SIZE, max_planes=99)
    assert set(pc.base) == {1, 2} and not pc.left_out
    x = project(ref, X)
    cams = {1: sup_a, 2: sup_b}
    # each point's hypothesis from the anchor's match, then the other support at that same hypothesis
    a, other = pc.anchor, 3 - pc.anchor
    xa = project(cams[a], X)
    H = lambda j, r: pc.base[j] + r * pc.step[j]
    rho = []
    for p, q in zip(x, xa):         # solve q ~ H(a, r) p for r (one unknown, least squares)
        u, w = pc.base[a] @ np.append(p, 1.0), pc.step[a] @ np.append(p, 1.0)
        qh = np.append(q, 1.0)
        cu, cw = np.cross(qh, u), np.cross(qh, w)
        rho.append(-cu @ cw / (cw @ cw))
    got = np.array([(H(other, r) @ np.append(p, 1.0)) for p, r in zip(x, rho)])
    assert np.abs(got[:, :2] / got[:, 2:] - project(cams[other], X)).max() < 1e-4
    # the hypotheses swept cover the points, one grid pixel or less apart where they move most
    assert pc.rho.min() < min(rho) and pc.rho.max() > max(rho)
    assert 16 <= len(pc.rho) <= 99


def test_a_support_that_shares_too_few_tracks_is_left_out(three_views):
    X = three_views[3]
    ids_b = np.arange(len(X)) + 10_000                      # no reference keypoint in common
    pc = PC.shared_pencil(pairs_of(three_views, ids_b), SIZE, max_planes=99, min_supports=1)
    assert len(pc.base) == 1 and "tracks" in next(iter(pc.left_out.values()))
    assert PC.shared_pencil(pairs_of(three_views, ids_b), SIZE, max_planes=99) is None     # one is no sharing


def test_matches_on_one_plane_leave_a_range_but_no_second_support(three_views):
    """On one plane the tracks cannot tell how one support's pencil scales against another's."""
    ref, sup_a, sup_b, X = three_views
    X = X.copy()
    X[:, 1] = 2.0                                            # every point on the plane y = 2
    pc = PC.shared_pencil(pairs_of((ref, sup_a, sup_b, X)), SIZE, max_planes=99, min_supports=1)
    assert len(pc.base) == 1 and "one plane" in next(iter(pc.left_out.values()))
    x = project(ref, X)[:1]
    ends = [pc.base[pc.anchor] + r * pc.step[pc.anchor] for r in (pc.rho[0], pc.rho[-1])]
    q = np.array([H @ np.append(x[0], 1.0) for H in ends])
    span = np.linalg.norm(q[0, :2] / q[0, 2] - q[1, :2] / q[1, 2])
    assert span > PC.MIN_SPAN_FRAC * max(SIZE)                   # about twice, projectively
    # the least range is a share of the working side: in a set run at twice the size, twice as long
    wide = PC.shared_pencil(pairs_of((ref, sup_a, sup_b, X)), SIZE, max_planes=99, min_supports=1, working_side=1280)
    ends = [wide.base[wide.anchor] + r * wide.step[wide.anchor] for r in (wide.rho[0], wide.rho[-1])]
    q = np.array([H @ np.append(x[0], 1.0) for H in ends])
    assert np.linalg.norm(q[0, :2] / q[0, 2] - q[1, :2] / q[1, 2]) > 1.8 * span


def test_a_mover_has_no_hypothesis_its_supports_agree_on():
    """The image test of the camera sweep (test_sweep.py), swept over a pencil built from F and
    matches alone: the static plane matches at one hypothesis, the moved square at none."""
    from test_sweep import DEPTH, K, SIZE as S, render, ref_box, grid, texture, camera
    from pipeline import sweep as SW
    sp = SweepParams(enabled=True, scale=0.5, n_planes=48, window=7, blur=1.0, two_view=True)
    tex = texture()
    cams = [camera(0.0), camera(0.5), camera(-0.5, 0.2), camera(0.3, -0.3)]
    red = (230, 30, 30)
    places = [(0.0, 0.0), (0.9, 0.4), (-0.9, -0.3), (0.5, -0.8)]
    imgs = [render(c, tex, [(x, y, 0.35, red)]) for c, (x, y) in zip(cams, places)]
    P = [Kc @ np.hstack([R, -R @ C[:, None]]) for Kc, R, C in cams]
    # "matches" at several depths (on one plane the supports' pencils could not be aligned): the
    # pencil needs F and where matches lie, not what the photos show there
    rng = np.random.default_rng(1)
    Xw = np.column_stack([rng.uniform(-2.5, 2.5, 80), rng.uniform(-2, 2, 80), rng.uniform(2.5, 8, 80), np.ones(80)])
    pix = [(Xw @ Pk.T)[:, :2] / (Xw @ Pk.T)[:, 2:] for Pk in P]
    pc = PC.shared_pencil({k: (fundamental_from_cameras(P[0], P[k]), pix[0], pix[k], np.arange(80)) for k in (1, 2, 3)},
                          S, max_planes=60)
    assert set(pc.base) == {1, 2, 3}
    pairs = [SW.pencil_pair(0, k, imgs[0], imgs[k], pc.homographies(k), sp) for k in (1, 2, 3)]
    assert all(p.kind == "two-view" and p.cost.shape[2] == len(pc.rho) for p in pairs)
    f = SW.fuse(pairs, sp)
    mover = grid(ref_box(0.0, 0.0, 0.35))
    static = (slice(5, 15), slice(5, 30))
    assert np.nanmedian(f.cost[mover]) > 0.25
    assert np.nanmedian(f.cost[static]) < 0.1
