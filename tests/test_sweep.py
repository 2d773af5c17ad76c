"""The depth-consistent cue (pipeline/sweep.py) and the peer baseline (pipeline/peer.py):
properties, on images made here from a textured plane and known cameras."""

import dataclasses

import numpy as np
import pytest

from pipeline import sweep as SW
from pipeline.params import SweepParams

SP = SweepParams(enabled=True, scale=0.5, n_planes=48, window=7, blur=1.0)
SIZE = (160, 200)
K = np.array([[180.0, 0, 99.5], [0, 180.0, 79.5], [0, 0, 1]])
DEPTH = 4.0


def camera(x: float, y: float = 0.0):
    return K, np.eye(3), np.array([x, y, 0.0])


def texture(seed=0, size=(400, 480)):
    rng = np.random.default_rng(seed)
    import cv2
    t = rng.integers(0, 255, (size[0] // 8, size[1] // 8, 3), dtype=np.uint8)
    return cv2.resize(t, (size[1], size[0]), interpolation=cv2.INTER_CUBIC)


def render(cam, tex, blobs=()):
    """The photo of a fronto-parallel textured plane at z = DEPTH (the world frame is the reference
    camera's), with square 'movers' (x, y world on the plane, size m, colour) pasted on it."""
    import cv2
    Kc, R, C = cam
    h, w = SIZE
    # plane point (u, v) of the texture -> world (X, Y, DEPTH); texture spans 6 m x 5 m
    S = np.array([[6.0 / tex.shape[1], 0, -3.0], [0, 5.0 / tex.shape[0], -2.5], [0, 0, 1.0]])
    P = Kc @ np.hstack([R, -R @ C[:, None]])
    Hp = P @ np.array([[1, 0, 0], [0, 1, 0], [0, 0, DEPTH], [0, 0, 1.0]]) @ S      # texture px -> image
    img = cv2.warpPerspective(tex, Hp, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    for (X, Y, m, col) in blobs:
        q = P @ np.array([[X - m, Y - m, DEPTH, 1], [X + m, Y + m, DEPTH, 1]]).T
        (x0, x1), (y0, y1) = q[0] / q[2], q[1] / q[2]
        img[int(y0):int(y1), int(x0):int(x1)] = col
    return img


def ref_box(X, Y, m):
    """The pixel box of a blob in the reference (camera at the origin)."""
    q = K @ np.array([[X - m, Y - m, DEPTH], [X + m, Y + m, DEPTH]]).T
    (x0, x1), (y0, y1) = q[0] / q[2], q[1] / q[2]
    return slice(int(y0), int(y1)), slice(int(x0), int(x1))


def grid(box):
    """A working-resolution box on the sweep grid (scale 0.5), shrunk by the window's half."""
    ys, xs = box
    return slice(ys.start // 2 + 3, ys.stop // 2 - 3), slice(xs.start // 2 + 3, xs.stop // 2 - 3)


@pytest.fixture(scope="module")
def scene():
    tex = texture()
    cams = [camera(0.0), camera(0.5), camera(-0.5, 0.2), camera(0.3, -0.3)]
    inv = SW.inverse_depths((1.5, np.inf), SP.n_planes)
    return tex, cams, inv


def volumes(imgs, cams, inv):
    return [SW.sweep_pair(0, k, imgs[0], imgs[k], cams[0], cams[k], inv, SP) for k in range(1, len(imgs))]


def test_static_plane_gets_one_consistent_depth_and_a_low_cost(scene):
    tex, cams, inv = scene
    imgs = [render(c, tex) for c in cams]
    f = SW.fuse(volumes(imgs, cams, inv), SP)
    centre = (slice(25, 55), slice(30, 70))
    assert np.nanmedian(f.cost[centre]) < 0.08
    true_plane = int(np.argmin(np.abs(inv - 1.0 / DEPTH)))
    assert np.mean(np.abs(f.plane[centre].astype(int) - true_plane) <= 1) > 0.9


def test_an_object_that_moved_has_no_consistent_depth(scene):
    tex, cams, inv = scene
    red, blue = (230, 30, 30), (30, 30, 230)
    # the mover is at a different place in every shot (and another colour in one)
    places = [(0.0, 0.0), (0.9, 0.4), (-0.9, -0.3), (0.5, -0.8)]
    imgs = [render(c, tex, [(x, y, 0.35, red if k != 2 else blue)]) for k, (c, (x, y)) in enumerate(zip(cams, places))]
    f = SW.fuse(volumes(imgs, cams, inv), SP)
    mover = grid(ref_box(0.0, 0.0, 0.35))
    static = (slice(5, 15), slice(5, 30))
    assert np.nanmedian(f.cost[mover]) > 0.25
    assert np.nanmedian(f.cost[static]) < 0.1


def test_a_support_where_the_point_is_hidden_does_not_veto(scene):
    """One of three supports sees something else in front of the point (an occluder): the best
    half of the supports still agree, the point stays static."""
    tex, cams, inv = scene
    imgs = [render(c, tex) for c in cams]
    # occluder in support 1 at the projection of the reference's centre region
    q = K @ (np.array([0.0, 0.0, DEPTH]) - cams[1][2])
    x, y = int(q[0] / q[2]), int(q[1] / q[2])
    imgs[1] = imgs[1].copy()
    imgs[1][y - 25:y + 25, x - 25:x + 25] = (250, 250, 0)
    f = SW.fuse(volumes(imgs, cams, inv), SP)
    centre = grid(ref_box(0.0, 0.0, 0.3))
    assert np.nanmedian(f.cost[centre]) < 0.1
    s1 = 0                                      # support 1's own cost there is high: it was out-voted
    assert np.nanmedian(f.per_support[s1][centre]) > 0.2


def test_direct_comparison_finds_a_pasted_object():
    """Two shots from one spot (identity alignment): a pasted object differs, the rest does not."""
    tex = texture(1)
    a = render(camera(0.0), tex)
    b = a.copy()
    b[60:100, 80:120] = (20, 200, 20)
    r = SW.aligned_pair(0, 1, a, b, np.ones(SIZE, np.float32), SP)
    cost = r.cost[:, :, 0].astype(float) / SW.SCALE
    assert cost[34:46, 44:56].mean() > 0.3 and cost[5:20, 5:30].mean() < 0.05


def test_a_direct_comparison_on_a_finer_grid_is_fused_with_planes_at_theirs():
    """`aligned_side`: an aligned pair's one map at its own (finer) grid; beside a planes' volume
    on the coarser grid it is sampled down by nearest samples, so UNSEEN stays UNSEEN."""
    tex = texture(1)
    a = render(camera(0.0), tex)
    b = a.copy()
    b[60:100, 80:120] = (20, 200, 20)
    valid = np.ones(SIZE, np.float32)
    valid[:, :40] = 0.0                                      # the support does not cover the left
    fine = SW.aligned_pair(0, 1, a, b, valid, dataclasses.replace(SP, aligned_side=max(SIZE)))
    assert fine.cost.shape == (*SIZE, 1)
    capped = SW.aligned_pair(0, 1, a, b, valid, dataclasses.replace(SP, aligned_side=150))
    assert capped.cost.shape == (120, 150, 1)                # its longer side at most aligned_side
    cost = fine.cost[:, :, 0].astype(float) / SW.SCALE
    assert cost[70:90, 90:110].mean() > 0.3 and cost[10:40, 100:160].mean() < 0.05
    coarse = SW.sweep_size(SIZE, SP)
    down = SW.on_grid(fine, coarse)
    assert down.cost.shape == (*coarse, 1) and down.kind == "aligned"
    assert np.all(down.cost[:, :15] == SW.UNSEEN)            # nothing blended with UNSEEN
    assert set(np.unique(down.cost)) <= set(np.unique(fine.cost))
    assert SW.on_grid(down, coarse) is down


def test_the_fused_probability_is_monotone_in_each_cue():
    from pipeline.aggregate import dynamic_from_log_odds, support_log_odds
    from pipeline.params import get_preset
    from pipeline.run import calibrated_log_odds
    p = get_preset("default")
    costs = np.linspace(0, 1, 11, dtype=np.float32)
    assert np.all(np.diff(calibrated_log_odds(costs, p)) < 0)          # a higher cost: less static
    probs = np.linspace(0.01, 0.99, 11, dtype=np.float32)
    assert np.all(np.diff(support_log_odds(probs, p.aggregate)) > 0)   # a better match: more static
    z = np.linspace(-5, 5, 11, dtype=np.float32)
    assert np.all(np.diff(dynamic_from_log_odds(p.aggregate.calib_scale * (z - p.aggregate.calib_offset))) < 0)


def test_fusion_matches_a_plain_numpy_reference():
    rng = np.random.default_rng(3)
    pairs = [SW.SweepPair(0, k, rng.integers(0, 256, (6, 7, 5), dtype=np.uint8), np.zeros(5), 0.0) for k in range(4)]
    f = SW.fuse(pairs, SP)
    st = np.stack([p.cost for p in pairs]).astype(float)
    st[st == SW.UNSEEN] = np.inf
    st /= SW.SCALE
    n = np.isfinite(st).sum(0)
    k = np.maximum(np.ceil(n * SP.best_share), 1).astype(int)
    cs = np.cumsum(np.where(np.isfinite(np.sort(st, 0)), np.sort(st, 0), 0), 0)
    fused = np.take_along_axis(cs, (k - 1)[None], 0)[0] / k
    fused[n == 0] = np.inf
    want = fused.min(-1)
    np.testing.assert_allclose(np.where(np.isfinite(want), want, np.nan), f.cost, atol=1e-6)


def test_the_compiled_plane_pass_equals_its_numpy_definition(scene):
    """sweep_pair's per-plane pass (one 4-channel warp, then the window sums, the windows inside
    and SSIM in one compiled pass) gives the quantised ssim_cost of the plain warp: the colours with
    replicated borders, the valid mask warped on its own, its box filter above 0.999."""
    import cv2
    tex, cams, inv = scene
    ref, sup = render(cams[0], tex), render(cams[1], tex)
    got = SW.sweep_pair(0, 1, ref, sup, cams[0], cams[1], inv, SP).cost
    g = SW.sweep_size(SIZE, SP)
    A = SW.grid_matrix(SIZE, g)
    Hs = A[None] @ SW.plane_homographies(*cams[0], *cams[1], SW.reference_planes(inv)) @ np.linalg.inv(A)[None]
    rs = SW.ref_stats(SW.lab_image(ref, g, SP), SP.window)
    sup_lab = SW.lab_image(sup, g, SP)
    flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
    n_inside = 0
    for d, H in enumerate(Hs):
        img = cv2.warpPerspective(sup_lab, H, (g[1], g[0]), flags=flags, borderMode=cv2.BORDER_REPLICATE)
        ones = cv2.warpPerspective(np.ones(sup_lab.shape[:2], np.float32), H, (g[1], g[0]), flags=flags,
                                   borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        valid = (ones > 0.999).astype(np.float32)
        inside = SW._box(valid, SP.window) > 0.999
        want = SW._quantise(SW.ssim_cost(rs, img, valid, SP.window, SP))
        assert np.array_equal(got[..., d] == SW.UNSEEN, ~inside)
        # equal but where a tap of weight 1/1024 falls outside the support (the ones channel is
        # then 0.999: valid), whose colour the border mode sets: at most one step, rarely
        diff = np.abs(got[..., d].astype(int) - want.astype(int))[inside]
        assert diff.max(initial=0) <= 1 and (diff > 0).mean() < 1e-3
        n_inside += int(inside.sum())
    assert n_inside > 0.3 * got.size                # the planes do overlap the support


def test_peer_baseline_finds_a_pasted_object_under_pure_rotation():
    import cv2

    from pipeline.peer import difference, dynamic_from_differences
    tex = texture(2)
    a = render(camera(0.0), tex)
    ang = np.deg2rad(4)
    R = np.array([[np.cos(ang), 0, np.sin(ang)], [0, 1, 0], [-np.sin(ang), 0, np.cos(ang)]])
    H = K @ R @ np.linalg.inv(K)                               # a pure rotation: x_b ~ H x_a
    b = cv2.warpPerspective(a, H, (SIZE[1], SIZE[0]), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    a = a.copy()
    a[60:100, 80:120] = (240, 20, 20)                          # only in the reference
    p = dynamic_from_differences([difference(0, 1, a, b, H).diff])
    assert p[70:90, 90:110].mean() > 0.8 and p[20:40, 20:60].mean() < 0.3


@pytest.mark.parametrize("min_agree", [1, 2, 3])
def test_fusion_kernel_equals_its_numpy_definition_with_same_spot_supports(min_agree):
    rng = np.random.default_rng(5)
    cost = rng.integers(0, 256, (5, 6, 7, 9), dtype=np.uint8)           # 5 supports, 6 x 7 pixels, 9 planes
    pairs = [SW.SweepPair(0, k + 1, cost[k], np.zeros((9, 4)), 0.0) for k in range(5)]
    same = np.array([True, False, False, True, False])
    sp = dataclasses.replace(SP, min_agree=min_agree)
    f = SW.fuse(pairs, sp, same)
    for y in range(6):
        for x in range(7):
            curve = SW.fused_costs(cost[:, y, x], same, sp.best_share, min_agree)
            if np.all(np.isnan(curve)):
                assert f.plane[y, x] == -1 and np.isnan(f.cost[y, x])
                continue
            assert f.cost[y, x] == pytest.approx(np.nanmin(curve), abs=1e-6)
            assert curve[f.plane[y, x]] == pytest.approx(np.nanmin(curve), abs=1e-6)


def test_one_look_alike_of_two_supports_is_agreement_only_when_min_agree_allows():
    """Of two supports the best half is one: by default one support's match makes the point static;
    with min_agree 2 both are averaged where both see it, and a point one alone sees keeps its cost."""
    look_alike = np.full((1, 2, 3), 254, np.uint8)
    look_alike[0, :, 1] = 0                                     # a perfect match at plane 1
    other = np.full((1, 2, 3), 200, np.uint8)
    other[0, 1] = SW.UNSEEN                                     # pixel 1: only the look-alike sees it
    pairs = [SW.SweepPair(0, 1, look_alike, np.zeros((3, 4)), 0.0), SW.SweepPair(0, 2, other, np.zeros((3, 4)), 0.0)]
    alone = SW.fuse(pairs, SP)
    both = SW.fuse(pairs, dataclasses.replace(SP, min_agree=2))
    assert alone.cost[0, 0] == pytest.approx(0.0)
    assert both.cost[0, 0] == pytest.approx(100 / SW.SCALE, abs=1e-6)    # the mean of 0 and 200
    assert alone.cost[0, 1] == both.cost[0, 1] == pytest.approx(0.0)


def test_two_supports_agree_only_where_a_reference_has_just_two():
    """two_supports_agree: a reference with two swept supports averages both; with a third support
    the best half is two anyway, and the rule changes nothing."""
    look_alike = np.full((1, 1, 3), 254, np.uint8)
    look_alike[0, 0, 1] = 0                                     # a perfect match at plane 1
    other = np.full((1, 1, 3), 200, np.uint8)
    pairs = [SW.SweepPair(0, 1, look_alike, np.zeros((3, 4)), 0.0), SW.SweepPair(0, 2, other, np.zeros((3, 4)), 0.0)]
    agree = dataclasses.replace(SP, two_supports_agree=True)
    assert SW.fuse(pairs, SP).cost[0, 0] == pytest.approx(0.0)
    assert SW.fuse(pairs, agree).cost[0, 0] == pytest.approx(100 / SW.SCALE, abs=1e-6)
    assert SW.agree_count(agree, 2) == 2 and SW.agree_count(agree, 3) == 1 and SW.agree_count(SP, 2) == 1
    three = pairs + [SW.SweepPair(0, 3, other.copy(), np.zeros((3, 4)), 0.0)]
    np.testing.assert_array_equal(SW.fuse(three, SP).cost, SW.fuse(three, agree).cost)


def test_a_support_from_the_same_spot_is_never_dropped_as_occluded():
    # three supports agree at plane 2; the one taken from the reference's spot sees no match there
    cost = np.full((4, 1, 1, 5), 200, np.uint8)
    cost[:3, 0, 0, 2] = 10
    cost[3] = 220
    pairs = [SW.SweepPair(0, k + 1, cost[k], np.zeros((5, 4)), 0.0) for k in range(4)]
    lenient = SW.fuse(pairs, SP)
    strict = SW.fuse(pairs, SP, np.array([False, False, False, True]))
    assert lenient.cost[0, 0] == pytest.approx(10 / SW.SCALE)            # the best half: the three that agree
    assert strict.cost[0, 0] > 0.3                                       # the same-spot support's "no" counts


def test_smoothing_keeps_a_consistent_depth_and_denies_scattered_look_alikes():
    rng = np.random.default_rng(7)
    H, W, D = 40, 60, 30
    cost = rng.integers(60, 120, (3, H, W, D)).astype(np.uint8)         # no plane matches well ...
    cost[:, :, :, 12] = 15                                               # ... except the scene's depth
    rows, cols = slice(10, 30), slice(20, 40)
    mover = np.zeros((H, W), bool)
    mover[rows, cols] = True
    cost[:, mover, 12] = 110                                             # the mover: no match at the scene's depth,
    look_alike = rng.integers(0, D, mover.sum())                         # a look-alike at a random plane per pixel
    cost[:, mover, look_alike] = 15
    pairs = [SW.SweepPair(0, k + 1, cost[k], np.zeros((D, 4)), 0.0) for k in range(3)]
    plain = SW.fuse(pairs, SP)
    smooth = SW.fuse(pairs, dataclasses.replace(SP, smooth_p2=2.0, smooth_p1=0.3))
    assert np.all(smooth.cost >= plain.cost - 1e-6)                      # never better than the best plane
    assert np.mean(smooth.plane[~mover] == 12) > 0.99 and smooth.cost[~mover].max() < 0.07
    assert plain.cost[mover].max() < 0.07                                # each pixel alone finds its look-alike,
    assert np.median(smooth.cost[mover]) > 0.2                           # one smooth depth does not


def _sgm_reference(cost, n_fronto, p1, p2, n_paths):
    """Hirschmueller's path recursion written out plainly, path by path and pixel by pixel:
    L(p, d) = C(p, d) + min(L(p-r, d), L(p-r, d+-1) + P1, min_k L(p-r, k) + P2) - min_k L(p-r, k),
    with no P1 step between the two families of planes (parallel to the image: d < n_fronto)."""
    H, W, D = cost.shape
    total = np.zeros_like(cost, dtype=np.float64)
    for dy, dx in [(0, 1), (0, -1), (1, 0), (-1, 0), (1, 1), (-1, -1), (1, -1), (-1, 1)][:n_paths]:
        L = np.zeros_like(total)
        ys = range(H) if dy >= 0 else range(H - 1, -1, -1)
        xs = list(range(W)) if dx >= 0 else list(range(W - 1, -1, -1))
        for y in ys:
            for x in xs:
                py, px = y - dy, x - dx
                if not (0 <= py < H and 0 <= px < W):
                    L[y, x] = cost[y, x]
                    continue
                prev, low = L[py, px], L[py, px].min()
                for d in range(D):
                    best = min(prev[d], low + p2)
                    if d > 0 and d != n_fronto:
                        best = min(best, prev[d - 1] + p1)
                    if d + 1 < D and d + 1 != n_fronto:
                        best = min(best, prev[d + 1] + p1)
                    L[y, x, d] = cost[y, x, d] + best - low
        total += L
    return total


@pytest.mark.parametrize("n_paths", [4, 8])
def test_the_compiled_smoothing_is_hirschmuellers_recursion_along_every_path(n_paths):
    cost = np.random.default_rng(3).random((9, 11, 7)).astype(np.float32)
    total = SW._sgm_kernel(cost, 4, 0.3, 2.0, n_paths)
    np.testing.assert_allclose(total, _sgm_reference(cost.astype(np.float64), 4, 0.3, 2.0, n_paths), atol=1e-5)
    assert not np.allclose(total, _sgm_reference(cost.astype(np.float64), 0, 0.3, 2.0, n_paths), atol=1e-3)


def test_depth_span_is_zero_from_one_spot_and_grows_with_the_baseline():
    ang = np.deg2rad(10)
    R = np.array([[np.cos(ang), 0, np.sin(ang)], [0, 1, 0], [-np.sin(ang), 0, np.cos(ang)]])
    ref = (K, np.eye(3), np.zeros(3))
    assert SW.depth_span_px(ref, (K, R, np.zeros(3)), 1.5, SIZE) < 1e-6
    small = SW.depth_span_px(ref, (K, R, np.array([0.01, 0, 0])), 1.5, SIZE)
    assert 0 < small < 2.0
    sideways = SW.depth_span_px(ref, (K, np.eye(3), np.array([0.5, 0, 0])), 1.5, SIZE)
    assert sideways == pytest.approx(180 * 0.5 / 1.5, rel=1e-6)          # f * baseline / near


def test_plane_log_odds_reads_the_peer_map_against_its_neutral_difference():
    from pipeline.peer import TAU, dynamic_from_differences, plane_log_odds
    d = np.array([[0.5, 34.5, 80.0, np.nan]], np.float32)
    other = np.array([[1.5, 34.5, 60.0, np.nan]], np.float32)
    z = plane_log_odds([d, other], 34.5)
    med = np.array([1.0, 34.5, 70.0])
    p = 1 - np.exp(-med / TAU)
    want = np.log(np.expm1(34.5 / TAU)) - np.log(p / (1 - p))
    np.testing.assert_allclose(z[0, :3], want, atol=1e-4)
    assert z[0, 0] > 0 and abs(z[0, 1]) < 1e-5 and z[0, 2] < 0         # static below the neutral, moving above
    assert z[0, 3] == pytest.approx(np.log(np.expm1(34.5 / TAU)), rel=1e-5)   # uncovered: the peer's 0.5, mildly
    assert z[0, 3] > 2.0                                                       # static (about log 9)
    assert dynamic_from_differences([d, other])[0, 3] == 0.5


def test_plane_difference_needs_a_homography_of_enough_matches():
    from pipeline.peer import plane_difference
    tex = texture(3)
    a = render(camera(0.0), tex)
    rng = np.random.default_rng(0)
    pts = rng.uniform(20, 200, (60, 2)).astype(np.float32)
    diff, H = plane_difference(0, 1, a, a, pts, pts + 3.0, 3.0, 40)         # a pure shift of the same photo
    assert H is not None and np.allclose(H, [[1, 0, 3], [0, 1, 3], [0, 0, 1]], atol=1e-3)
    assert diff.shape == a.shape[:2] and np.isnan(diff).any()                 # the shifted border is uncovered
    assert plane_difference(0, 1, a, a, pts[:20], pts[:20] + 3.0, 3.0, 40) == (None, None)


@pytest.mark.parametrize("n_supports", [1, 2, 5, 8])
def test_median_difference_is_nanmedian_over_the_covering_supports(n_supports):
    from pipeline.peer import median_difference
    rng = np.random.default_rng(n_supports)
    diffs = [np.where(rng.random((30, 40)) < 0.3, np.nan, rng.random((30, 40)) * 80).astype(np.float32)
             for _ in range(n_supports)]
    diffs[0][:3] = np.nan
    for d in diffs:
        d[:2] = np.nan                                    # rows no support covers
    stack = np.stack(diffs)
    with np.errstate(all="ignore"), __import__("warnings").catch_warnings():
        __import__("warnings").simplefilter("ignore", RuntimeWarning)
        want = np.nanmedian(stack, axis=0).astype(np.float32)
    got = median_difference(diffs)
    assert got.dtype == np.float32 and np.isnan(got[:2]).all()
    np.testing.assert_array_equal(got, want)


def test_a_plane_out_of_view_warps_nothing_of_the_support():
    """planes_in_view may skip a plane only where the warp holds nothing of the support (every
    bilinear tap outside it); planes on both sides of the line at infinity included."""
    rng = np.random.default_rng(0)
    sup = np.ones((42, 56, 4), np.float32)
    grid = (48, 64)
    Hs = np.stack([np.eye(3) + rng.normal(0, [[0.3, 0.3, 30], [0.3, 0.3, 30], [0.004, 0.004, 0.2]])
                   for _ in range(600)])
    in_view = SW.planes_in_view(Hs, sup.shape[:2], grid)
    assert 20 < (~in_view).sum() < 580
    for H in Hs[~in_view]:
        assert not SW.warp(sup, H, grid).any()


@pytest.mark.parametrize("shape", [(99, 24, 37), (1, 8, 9), (5, 33, 16)])
def test_the_compiled_planes_last_copy_is_numpys_transpose(shape):
    """sweep_pair's volume from its planes: the compiled copy equals numpy's transposed copy."""
    per_plane = np.random.default_rng(0).integers(0, 256, shape, dtype=np.uint8)
    got = SW._planes_last_kernel(per_plane)
    assert got.flags.c_contiguous and np.array_equal(got, per_plane.transpose(1, 2, 0))


def test_fusion_by_bands_of_rows_equals_fusion_in_one_band(monkeypatch):
    """fuse copies the supports' costs for its kernel a band of rows at a time (memory): one row per
    band gives the same volume, planes, counts and per-support costs as one band for all."""
    rng = np.random.default_rng(11)
    cost = rng.integers(0, 256, (4, 9, 8, 6), dtype=np.uint8)
    pairs = [SW.SweepPair(0, k + 1, cost[k], np.zeros((6, 4)), 0.0) for k in range(3)]
    pairs.append(SW.SweepPair(0, 4, cost[3][..., :1], np.zeros((0, 4)), 0.0))     # an aligned pair: every plane
    same = np.array([False, True, False, False])
    whole = SW.fuse(pairs, SP, same)
    monkeypatch.setattr(SW, "BAND_BYTES", 1)
    banded = SW.fuse(pairs, SP, same)
    assert (whole.plane >= 0).any()
    for field in ("cost", "plane", "n_seen", "per_support"):
        np.testing.assert_array_equal(getattr(whole, field), getattr(banded, field))
