"""Depth-consistent evidence (`default` preset): one depth shared by all supports (a plane sweep).

The paper asks each support alone whether *some* similar patch lies *anywhere* along the epipolar
strip (§3.1). Along a strip that crosses a cluttered scene a mover often finds a look-alike, in
most supports. A static point must be at *one* depth that every support seeing it agrees on; a
mover has no such depth (EVIDENCE_NOTES: 1.6-9x the Jaccard of searching each support alone with
the same cost). With the set's cameras (reconstruction.py) we sweep planes parallel to the
reference image through the depth range its sparse points allow (the strip, bounded), warp every
support onto each plane (plane-induced homographies: the candidate patches are warped for the
viewpoint change, which the paper's axis-aligned patches cannot be), and compare windows with a
colour SSIM cost.

Per pair (reference i, support j) the result is a cost volume (D planes x h x w) at a reduced
resolution; a support from the same spot whose camera is unknown (a homography pair) gives one
depth-independent cost map instead (direct comparison of aligned pixels), and the supports of a
photo without a camera are swept over a pencil of planes their F's share (pencil.py). Per reference,
`fuse` takes at each depth the mean cost of the best half of the supports that see the point
(a support where the point is hidden must not veto it) and keeps the best depth. A point that no
support sees has no evidence.

Shapes: costs are uint8 volumes (h, w, D), cost in [0, 1] scaled by 254, UNSEEN (255) where the support
does not see the point; planes are indexed from near to far (uniform in inverse depth).
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import cv2
import numpy as np

from .jit import LazyKernel
from .params import SweepParams

UNSEEN = 255
SCALE = 254.0
BAND_BYTES = 32 << 20    # fuse: the supports' costs of a band of rows, copied together for the kernel


@dataclass(frozen=True)
class SweepPair:
    """Cost volume of reference `ref` against support `sup` (kind "sweep", D planes), or its
    depth-independent cost map (kind "aligned", D = 1), at the sweep's resolution (h, w) (an
    "aligned" map at its own, up to `aligned_side`; on_grid brings it to the planes').

    cost: (h, w, D) uint8, cost * 254 or UNSEEN (planes last: the fusion reads a pixel's planes
    contiguously); planes: (D, 4) float64 the planes n . X = d in the reference camera's frame
    (n unit, d = inf for the plane at infinity; see reference_planes), empty for "aligned" and
    "two-view"; seconds: compute time; kind: "sweep" (the set's cameras), "aligned" (a support from
    the same spot, compared directly) or "two-view" (a pencil of planes without cameras, pencil.py);
    homographies: for "two-view", (D, 3, 3) float64 reference -> support working px per plane.
    """

    ref: int
    sup: int
    cost: np.ndarray
    planes: np.ndarray
    seconds: float
    kind: str = "sweep"
    homographies: np.ndarray | None = None

    def depth_at(self, plane: np.ndarray, xy: np.ndarray, K: np.ndarray) -> np.ndarray:
        """Depth (reference camera z) of the pixels xy (N, 2) on the given plane indices (N,):
        (N,) float64, inf on the plane at infinity."""
        r = np.column_stack([np.asarray(xy, float), np.ones(len(xy))]) @ np.linalg.inv(K).T      # z = 1
        P = self.planes[np.asarray(plane)]
        with np.errstate(divide="ignore", invalid="ignore"):
            z = P[:, 3] / np.sum(P[:, :3] * r, axis=1)
        return np.where(np.isfinite(P[:, 3]) & (z > 0), z, np.inf)


@dataclass(frozen=True)
class Fused:
    """The supports' answers fused at one depth per pixel (sweep resolution h x w).

    cost: (h, w) float32 in [0, 1], fused cost at the best depth (NaN where no support sees);
    plane: (h, w) int16 best plane index (-1 without evidence); n_seen: (h, w) uint8 supports
    that see the point at that depth; per_support: (S, h, w) float32 each support's cost at the
    chosen plane (NaN where it does not see it), in the order of the given pairs.
    """

    cost: np.ndarray
    plane: np.ndarray
    n_seen: np.ndarray
    per_support: np.ndarray


# ----------------------------------------------------------------------------- geometry
def sweep_size(size: tuple[int, int], sp: SweepParams, scale: float | None = None) -> tuple[int, int]:
    """(h, w) of the sweep grid for a working-resolution (h, w) (at `scale` instead of sp.scale)."""
    h, w = size
    s = sp.scale if scale is None else scale
    return max(8, int(round(h * s))), max(8, int(round(w * s)))


def on_grid(pair: SweepPair, grid: tuple[int, int]) -> SweepPair:
    """The pair with its cost volume at another grid (h, w): nearest samples, so that UNSEEN stays
    UNSEEN and a cost is never a blend with it. A direct comparison made finer than the planes'
    sweep (`aligned_side`) is fused with them at theirs."""
    if pair.cost.shape[:2] == tuple(grid):
        return pair
    cost = cv2.resize(pair.cost, (grid[1], grid[0]), interpolation=cv2.INTER_NEAREST)
    return dataclasses.replace(pair, cost=cost.reshape(grid[0], grid[1], pair.cost.shape[2]))


def grid_matrix(size: tuple[int, int], grid: tuple[int, int]) -> np.ndarray:
    """3x3 map from working pixels to sweep-grid pixels (pixel centres at integers)."""
    sy, sx = grid[0] / size[0], grid[1] / size[1]
    return np.array([[sx, 0, 0.5 * sx - 0.5], [0, sy, 0.5 * sy - 0.5], [0, 0, 1.0]])


def inverse_depths(depth_range: tuple[float, float], n: int) -> np.ndarray:
    """(n,) inverse depths from near to far, uniform in inverse depth (a step then moves the
    match by about the same number of pixels anywhere in the range). far = inf puts the last plane
    at infinity (sky, distant buildings, what lies beyond the sparse points)."""
    near, far = float(depth_range[0]), float(depth_range[1])
    return np.linspace(1.0 / near, 0.0 if not np.isfinite(far) else 1.0 / far, n)


def reference_planes(inv_depths: np.ndarray, ground: tuple[np.ndarray, float] | None = None,
                     n_ground: int = 0) -> np.ndarray:
    """(D, 4) planes n . X = d in the reference camera's frame: first one parallel to the image
    (n = (0, 0, 1), d = 1 / inv_depth; inf for inv_depth 0), then, when `ground` = (n_c, height)
    gives the ground plane (unit normal n_c pointing up, in the camera frame, and the camera's
    height above it), `n_ground` planes parallel to the ground from it up to just below the camera.

    Near, slanted ground is where planes parallel to the image fail: a window on it spans many
    depths (measured on courtyard_static, the largest false positives of the depth cue)."""
    inv = np.asarray(inv_depths, float)
    with np.errstate(divide="ignore"):
        d = np.where(inv > 0, 1.0 / np.where(inv > 0, inv, 1.0), np.inf)
    planes = [np.column_stack([np.zeros((len(inv), 2)), np.ones(len(inv)), d])]
    if ground is not None and n_ground > 0:
        n_c, height = ground
        heights = np.linspace(0.0, 0.95 * height, n_ground)
        planes.append(np.column_stack([np.tile(n_c, (n_ground, 1)), heights - height]))
    return np.concatenate(planes)


def plane_homographies(K_i, R_i, C_i, K_j, R_j, C_j, planes: np.ndarray) -> np.ndarray:
    """(D, 3, 3) homographies mapping reference pixels to support pixels for the planes
    n . X_i = d ((D, 4), reference_planes): H = K_j (R + t n^T / d) K_i^-1 with X_j = R X_i + t
    the relative pose (HZ 13.1); d = inf is the plane at infinity, H = K_j R K_i^-1."""
    R = R_j @ R_i.T
    t = R_j @ (C_i - C_j)
    Ki_inv = np.linalg.inv(K_i)
    out = []
    for n0, n1, n2, d in planes:
        q = 0.0 if not np.isfinite(d) else 1.0 / d
        out.append(K_j @ (R + np.outer(t, (n0, n1, n2)) * q) @ Ki_inv)
    return np.stack(out)


# ----------------------------------------------------------------------------- images
def lab_image(rgb: np.ndarray, grid: tuple[int, int], sp: SweepParams) -> np.ndarray:
    """(h, w, 3) uint8 RGB -> (gh, gw, 3) float32 Lab at the sweep grid, a and b weighted
    (colour separates movers from look-alikes better than grey: EVIDENCE_NOTES point 3)."""
    small = cv2.resize(rgb, (grid[1], grid[0]), interpolation=cv2.INTER_AREA)
    lab = cv2.cvtColor(small.astype(np.float32) / 255.0, cv2.COLOR_RGB2Lab)
    if sp.blur > 0:        # tolerance to the sub-plane misalignment of fine texture
        lab = cv2.GaussianBlur(lab, (0, 0), sp.blur)
    return lab * np.array(sp.lab_weights, np.float32)


def _box(x: np.ndarray, k: int) -> np.ndarray:
    return cv2.boxFilter(x, cv2.CV_32F, (k, k), borderType=cv2.BORDER_REFLECT)


@dataclass(frozen=True)
class RefStats:
    """Window statistics of the reference, computed once per reference: mean and variance per
    channel, (h, w, 3) float32."""

    lab: np.ndarray
    mean: np.ndarray
    var: np.ndarray


def ref_stats(lab: np.ndarray, k: int) -> RefStats:
    mean = _box(lab, k)
    return RefStats(lab, mean, np.maximum(_box(lab * lab, k) - mean * mean, 0.0))


def ssim_cost(ref: RefStats, sup: np.ndarray, valid: np.ndarray, k: int, sp: SweepParams) -> np.ndarray:
    """Colour SSIM cost of an aligned support: (h, w) float32 in [0, 1] (0 = identical windows),
    NaN where the window is not wholly inside the support.

    sup: (h, w, 3) float32 Lab (weighted) aligned to the reference; valid: (h, w) float32 1 inside.
    Cost = (1 - mean over channels of SSIM) / 2 (Wang et al. 2004, per channel)."""
    mu = _box(sup, k)
    var = np.maximum(_box(sup * sup, k) - mu * mu, 0.0)
    cov = _box(ref.lab * sup, k) - ref.mean * mu
    c1, c2 = sp.ssim_c1, sp.ssim_c2
    lum = (2 * ref.mean * mu + c1) / (ref.mean ** 2 + mu ** 2 + c1)
    if not sp.lightness_mean:       # brightness varies across the frame (vignetting, shading): L's mean is left out
        lum[..., 0] = 1.0
    ssim = lum * (2 * cov + c2) / (ref.var + var + c2)
    cost = (1.0 - ssim.mean(axis=2)) * 0.5
    if sp.color_weight > 0:
        dist = np.linalg.norm(ref.mean - mu, axis=2)
        cost = (1.0 - sp.color_weight) * cost + sp.color_weight * np.minimum(dist / sp.color_tau, 1.0)
    inside = _box(valid, k) > 0.999
    return np.where(inside, np.clip(cost, 0.0, 1.0), np.nan).astype(np.float32)


def _quantise(cost: np.ndarray) -> np.ndarray:
    q = np.round(np.nan_to_num(cost, nan=0.0) * SCALE).astype(np.uint8)
    q[np.isnan(cost)] = UNSEEN
    return q


def planes_in_view(Hs: np.ndarray, sup_size: tuple[int, int], grid: tuple[int, int]) -> np.ndarray:
    """(D,) bool: whether plane d's warp (Hs (D, 3, 3), reference grid -> support grid) brings any
    of the support into the reference grid; where not, every comparison is UNSEEN.

    The grid pixels that H maps into the support's rectangle are the rectangle's image under H^-1;
    while the rectangle does not cross the line H^-1 sends to infinity (its corners' w of one sign)
    that image is the quadrilateral of its corners, and a plane whose quadrilateral misses the grid
    sees nothing (the rectangle is taken 1 px wider: a bilinear tap inside gives a non-zero warp).
    About one plane in ten on square_people's pairs. (Warping only the quadrilateral's bounding box
    was tried too: OpenCV's warp of the whole grid passes the pixels outside the support quickly,
    and the box's own warp, offset and copy cost twice as much.)"""
    h, w = sup_size
    corners = np.array([[-1.0, -1.0, 1.0], [w, -1.0, 1.0], [w, h, 1.0], [-1.0, h, 1.0]])
    try:
        H_inv = np.linalg.inv(Hs)
    except np.linalg.LinAlgError:          # a plane through the support's centre: warp them all
        return np.ones(len(Hs), bool)
    q = np.einsum("dij,cj->dci", H_inv, corners)                       # (D, 4, 3)
    bounded = np.all(q[..., 2] > 1e-12, axis=1) | np.all(q[..., 2] < -1e-12, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        xy = q[..., :2] / q[..., 2:]
    lo, hi = np.nanmin(xy, axis=1), np.nanmax(xy, axis=1)             # (D, 2) x, y
    misses = (hi[:, 0] < -2) | (lo[:, 0] > grid[1] + 1) | (hi[:, 1] < -2) | (lo[:, 1] > grid[0] + 1)
    return ~(bounded & misses)


def warp(sup_ones: np.ndarray, H_grid: np.ndarray, grid: tuple[int, int]) -> np.ndarray:
    """The support sampled at H x for every reference grid pixel x, (h, w, 4) float32.

    sup_ones: (h, w, 4) float32, the support's colours and a channel of ones, warped together:
    where all four bilinear taps fall inside the support the ones channel is 1 (valid, > 0.999),
    and there the colours do not depend on the border mode; elsewhere the comparison is UNSEEN
    anyway. One 4-channel warp costs less than the colours' and the mask's apart."""
    flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
    return cv2.warpPerspective(sup_ones, H_grid, (grid[1], grid[0]), flags=flags, borderMode=cv2.BORDER_CONSTANT,
                               borderValue=0)


# ----------------------------------------------------------------------------- per pair
def sweep_pair(ref: int, sup: int, rgb_ref: np.ndarray, rgb_sup: np.ndarray, cam_ref: tuple, cam_sup: tuple,
               planes: np.ndarray, sp: SweepParams) -> SweepPair:
    """Cost volume of one support over the reference's planes.

    rgb_*: (h, w, 3) uint8 working-resolution photos (the support's colours already mapped to the
    reference's, photometric.py); cam_*: (K, R, C) at working resolution; planes: (D, 4)
    (reference_planes), or (D,) inverse depths of planes parallel to the image.
    """
    t0 = time.perf_counter()
    planes = np.asarray(planes, float)
    if planes.ndim == 1:
        planes = reference_planes(planes)
    cost = _cost_volume(rgb_ref, rgb_sup, plane_homographies(*cam_ref, *cam_sup, planes), sp)
    return SweepPair(ref, sup, cost, planes, time.perf_counter() - t0)


def _cost_volume(rgb_ref: np.ndarray, rgb_sup: np.ndarray, Hs: np.ndarray, sp: SweepParams) -> np.ndarray:
    """The cost volume (h, w, D) uint8 (SweepPair.cost) of a support warped by Hs (D, 3, 3),
    reference -> support working px (brought to the sweep grids here)."""
    g_ref, g_sup = sweep_size(rgb_ref.shape[:2], sp), sweep_size(rgb_sup.shape[:2], sp)
    A_ref, A_sup = grid_matrix(rgb_ref.shape[:2], g_ref), grid_matrix(rgb_sup.shape[:2], g_sup)
    Hs = A_sup[None] @ np.asarray(Hs, np.float64) @ np.linalg.inv(A_ref)[None]
    rs = ref_stats(lab_image(rgb_ref, g_ref, sp), sp.window)
    sup_lab = lab_image(rgb_sup, g_sup, sp)
    if sp.window % 2 == 0 or sp.window >= min(g_ref):      # the kernel reflects a window once at the borders
        raise ValueError(f"sweep.window {sp.window} must be odd and smaller than the sweep grid {g_ref}")
    per_plane = np.empty((len(Hs), *g_ref), np.uint8)
    lum_l = 1.0 if sp.lightness_mean else 0.0
    sup_ones = np.dstack([sup_lab, np.ones(sup_lab.shape[:2], np.float32)])
    in_view = planes_in_view(Hs, g_sup, g_ref)
    for d, H in enumerate(Hs):          # one warp and comparison per plane (a hypothesis, not a pixel)
        if not in_view[d]:
            per_plane[d] = UNSEEN
            continue
        per_plane[d] = _plane_kernel(warp(sup_ones, H, g_ref), rs.lab, rs.mean, rs.var, sp.window, float(sp.ssim_c1),
                                     float(sp.ssim_c2), lum_l, float(sp.color_weight), float(sp.color_tau))
    return _planes_last_kernel(per_plane)


def pencil_pair(ref: int, sup: int, rgb_ref: np.ndarray, rgb_sup: np.ndarray, Hs: np.ndarray,
                sp: SweepParams) -> SweepPair:
    """Cost volume of a support without cameras over its reference's shared pencil of planes
    (pencil.py; kind "two-view", no planes in a camera frame): Hs (D, 3, 3) maps reference to
    support working px for each hypothesis. rgb_* as in sweep_pair."""
    t0 = time.perf_counter()
    Hs = np.asarray(Hs, np.float64)
    cost = _cost_volume(rgb_ref, rgb_sup, Hs, sp)
    return SweepPair(ref, sup, cost, np.zeros((0, 4)), time.perf_counter() - t0, kind="two-view", homographies=Hs)


def aligned_pair(ref: int, sup: int, rgb_ref: np.ndarray, rgb_sup_aligned: np.ndarray, valid: np.ndarray,
                 sp: SweepParams) -> SweepPair:
    """Direct comparison for a support from the same spot (a homography pair without cameras):
    rgb_sup_aligned (h, w, 3) uint8 is the support warped into the reference frame, valid (h, w)
    its coverage. One depth-independent cost map (D = 1), on a grid whose longer side is at most
    `aligned_side` (and no coarser than the planes' sweep)."""
    t0 = time.perf_counter()
    # one depth-independent map, not a volume: it can afford a finer grid than the planes' sweep; at most
    # `aligned_side` px, so that its SSIM window keeps a footprint in the scene (7 px at 640: at 1280 the full
    # resolution's 7 px windows read a hand's plain skin as static, mcvav_usb_hand)
    scale = sp.scale if sp.aligned_side <= 0 else max(sp.scale, min(1.0, sp.aligned_side / max(rgb_ref.shape[:2])))
    g = sweep_size(rgb_ref.shape[:2], sp, scale)
    rs = ref_stats(lab_image(rgb_ref, g, sp), sp.window)
    sup = lab_image(rgb_sup_aligned, g, sp)
    vis = cv2.resize(valid.astype(np.float32), (g[1], g[0]), interpolation=cv2.INTER_AREA)
    cost = _quantise(ssim_cost(rs, sup, (vis > 0.999).astype(np.float32), sp.window, sp))[:, :, None]
    return SweepPair(ref, sup, cost, np.zeros((0, 4)), time.perf_counter() - t0, kind="aligned")


# ----------------------------------------------------------------------------- per reference
def depth_span_px(cam_ref: tuple, cam_sup: tuple, near: float, size: tuple[int, int], step: int = 16) -> float:
    """How far the support's match of a reference pixel travels as its depth goes from `near` to
    infinity: the 90th percentile over a grid of the reference (h, w) of that distance, in support
    pixels (cam_*: (K, R, C) at working resolution). Near 0: the two photos were taken from one
    spot, and every depth warps the support alike."""
    K_i, R_i, C_i = cam_ref
    K_j, R_j, C_j = cam_sup
    h, w = size
    ys, xs = np.mgrid[0:h:step, 0:w:step]
    ray = R_i.T @ np.linalg.inv(K_i) @ np.stack([xs.ravel(), ys.ravel(), np.ones(xs.size)])    # world directions
    X_near = C_i[:, None] + ray * (near / (R_i @ ray)[2])
    q_near = K_j @ (R_j @ (X_near - C_j[:, None]))
    q_far = K_j @ (R_j @ ray)
    ok = (q_near[2] > 1e-9) & (q_far[2] > 1e-9)
    if not ok.any():
        return float("inf")
    d = np.linalg.norm(q_near[:2, ok] / q_near[2, ok] - q_far[:2, ok] / q_far[2, ok], axis=0)
    return float(np.percentile(d, 90))


def fused_costs(costs: np.ndarray, same_spot: np.ndarray, share: float, min_agree: int = 1) -> np.ndarray:
    """The fusion of one pixel at every plane, in numpy (the compiled kernel's definition, for one
    pixel: explain.py and the tests).

    costs: (S, D) uint8 as in SweepPair.cost (UNSEEN where a support does not see the point);
    same_spot: (S,) bool. Returns (D,) float32 in [0, 1], NaN where no support sees the point:
    the mean of every same-spot support that sees the point and of the best `share` of the others,
    at least `min_agree` supports in all where that many see it.
    """
    vals = np.where(costs == UNSEEN, np.inf, costs.astype(np.float64))
    pinned = same_spot[:, None] & np.isfinite(vals)
    free = np.sort(np.where(same_spot[:, None], np.inf, vals), axis=0)
    n_free = np.isfinite(free).sum(axis=0)
    k = np.ceil(n_free * share).astype(int)
    k = np.where((k == 0) & (n_free > 0) & ~pinned.any(axis=0), 1, k)        # at least one support
    k = np.maximum(k, np.minimum(n_free, min_agree - pinned.sum(axis=0)))      # at least min_agree in all
    csum = np.concatenate([np.zeros((1, vals.shape[1])), np.cumsum(np.where(np.isfinite(free), free, 0.0), axis=0)])
    total = np.take_along_axis(csum, k[None], axis=0)[0] + np.where(pinned, vals, 0.0).sum(axis=0)
    count = k + pinned.sum(axis=0)
    return np.where(count > 0, total / np.maximum(count, 1) / SCALE, np.nan).astype(np.float32)


def agree_count(sp: SweepParams, n_swept: int) -> int:
    """The fewest supports the fusion averages where that many see a point (sweep.min_agree), for a
    reference with `n_swept` swept supports: with `two_supports_agree` a reference with only two
    averages both (of two the best half is one, and one look-alike would decide alone)."""
    return max(int(sp.min_agree), 2 if sp.two_supports_agree and n_swept == 2 else 1)


def fuse(pairs: list[SweepPair], sp: SweepParams, same_spot: np.ndarray | None = None) -> Fused:
    """One depth for all supports.

    At each plane, the mean cost of the best `best_share` of the supports that see the point (a
    support where the point is hidden must not veto it; but at least agree_count of them where
    that many see it: of two supports the best half is one, and one look-alike is no agreement),
    with the supports from the reference's own spot (same_spot, (S,) bool; depth_span_px) always
    counted: a photo taken from the same place cannot see behind what the reference sees, so its
    "no match" is never an occlusion. Then one plane per pixel: the best one, or with `smooth_p2`
    > 0 the one a semi-global regularisation of the fused volume picks (smooth_volume): the static
    scene's depth is smooth, a mover's accidental look-alike depths are not (EVIDENCE_NOTES point
    9). The cost reported is the fused
    cost at that plane.

    pairs: the reference's SweepPairs ("sweep" ones share the same planes; "aligned" ones count
    at every plane). Returns Fused at the sweep resolution.
    """
    assert pairs, "no support to fuse"
    D = max(p.cost.shape[2] for p in pairs)
    H, W = pairs[0].cost.shape[:2]
    costs = [np.broadcast_to(p.cost, (H, W, D)) for p in pairs]      # "aligned" ones count at every plane
    pinned = np.zeros(len(pairs), np.bool_) if same_spot is None else np.asarray(same_spot, np.bool_)
    volume = np.empty((H, W, D), np.float32)
    n_vol = np.empty((H, W, D), np.uint8)
    # The kernel reads the supports' costs as one (S, rows, W, D) array: made a band of rows at a time,
    # so that its copy stays small (every support's whole volume copied took 180 MB a reference at
    # 1280 px); each pixel's fusion is its own, so the bands give the same volume bit for bit.
    rows = max(1, BAND_BYTES // max(1, len(pairs) * W * D))
    for y0 in range(0, H, rows):
        band = np.ascontiguousarray(np.stack([c[y0:y0 + rows] for c in costs]))
        volume[y0:y0 + rows], n_vol[y0:y0 + rows] = _volume_kernel(
            band, pinned, float(sp.best_share), float(sp.min_seen_share), agree_count(sp, len(pairs)))
    if sp.smooth_p2 > 0:
        planes = next((p.planes for p in pairs if len(p.planes)), np.zeros((0, 4)))
        fronto = (planes[:, 0] == 0) & (planes[:, 1] == 0) & (planes[:, 2] == 1)     # listed first
        plane = smooth_volume(volume, sp, int(fronto.sum()) if len(planes) else D)
    else:
        plane = np.argmin(np.where(volume >= 0, volume, np.inf), axis=2).astype(np.int16)
    cost = np.take_along_axis(volume, plane[..., None].astype(np.intp), 2)[..., 0]
    seen = cost >= 0
    plane = np.where(seen, plane, -1).astype(np.int16)
    at = np.maximum(plane, 0).astype(np.intp)[None, ..., None]
    n_seen = np.where(seen, np.take_along_axis(n_vol, at[0], 2)[..., 0], 0).astype(np.uint8)
    per = np.stack([np.take_along_axis(c, at[0], 2)[..., 0] for c in costs])
    per = np.where(seen[None] & (per != UNSEEN), per.astype(np.float32) / SCALE, np.nan).astype(np.float32)
    return Fused(np.where(seen, cost, np.nan).astype(np.float32), plane, n_seen, per)


def smooth_volume(volume: np.ndarray, sp: SweepParams, n_fronto: int) -> np.ndarray:
    """The plane per pixel that semi-global matching (Hirschmueller 2008) picks on a fused volume
    (h, w, D) float32 (-1 where no support sees the point, costed `smooth_unseen`): path costs
    along `smooth_paths` directions with a penalty `smooth_p1` for a step to the next plane and
    `smooth_p2` for a jump; planes [0, n_fronto) (parallel to the image) and [n_fronto, D) (parallel
    to the ground) are two families, a change of family is a jump. Returns (h, w) int16."""
    cost = np.where(volume >= 0, volume, np.float32(sp.smooth_unseen)).astype(np.float32, copy=False)
    total = _sgm_kernel(cost, int(n_fronto), float(sp.smooth_p1), float(sp.smooth_p2), int(sp.smooth_paths))
    return np.argmin(total, axis=2).astype(np.int16)


def _volume_numba():
    """The fused volume (numba): per pixel and plane the mean of the smallest few of a handful of
    supports' costs, which numpy can only get by sorting every (plane, pixel) column.

    Per pixel, the free supports' cost rows (D planes each, contiguous) are inserted one after the
    other into per-plane sorted columns by compare-exchange (UNSEEN, 255, sorts last), a loop over
    the planes without branches that the compiler vectorises; then each plane sums its k smallest.
    The same sums as a selection per plane (the earlier kernel, 3-5x slower), so the same volume
    bit for bit."""
    import numba

    @numba.njit(parallel=True, cache=True, nogil=True)
    def kernel(stack, pinned, share, min_seen_share, min_agree):
        S, H, W, D = stack.shape
        volume = np.full((H, W, D), -1.0, np.float32)
        n_vol = np.zeros((H, W, D), np.uint8)
        for y in numba.prange(H):
            srt = np.empty((S, D), np.uint8)        # the free supports' costs per plane, ascending
            carry = np.empty(D, np.uint8)
            n_free = np.empty(D, np.int32)
            n_pin = np.empty(D, np.int32)
            pin_total = np.empty(D, np.int32)
            for x in range(W):
                n_free[:] = 0
                n_pin[:] = 0
                pin_total[:] = 0
                nf = 0
                for s_ in range(S):
                    v = stack[s_, y, x]
                    if pinned[s_]:                  # a same-spot support always counts where it sees
                        for d in range(D):
                            seen = v[d] != UNSEEN
                            n_pin[d] += seen
                            pin_total[d] += v[d] if seen else 0
                        continue
                    for d in range(D):
                        carry[d] = v[d]
                        n_free[d] += v[d] != UNSEEN
                    for p in range(nf):
                        row = srt[p]
                        for d in range(D):
                            a, b = row[d], carry[d]
                            row[d] = min(a, b)
                            carry[d] = max(a, b)
                    srt[nf, :] = carry
                    nf += 1
                # a plane seen by few of the supports that could see the point is no agreement: it
                # would win by having fewer costs to average (min_seen_share of the most at any plane)
                n_max = 0
                for d in range(D):
                    n_max = max(n_max, n_free[d] + n_pin[d])
                n_min = max(1, int(np.ceil(n_max * min_seen_share)))
                for d in range(D):
                    n = n_free[d]
                    if n + n_pin[d] < n_min:
                        continue
                    k = int(np.ceil(n * share))
                    if k == 0 and n_pin[d] == 0:
                        k = 1
                    k = max(k, min(n, min_agree - n_pin[d]))      # k <= n: only seen costs are summed
                    total = pin_total[d]
                    for p in range(k):
                        total += srt[p, d]
                    volume[y, x, d] = total / (k + n_pin[d]) / SCALE
                    n_vol[y, x, d] = n + n_pin[d]
        return volume, n_vol
    return kernel


def _sgm_numba():
    """Semi-global path costs (numba): each path is a recursion along one direction with an O(D)
    step, which numpy cannot vectorise. The volume is read in memory order: a horizontal path is a
    row, scanned by itself (rows in parallel); the other directions advance a whole row at a time,
    each pixel continuing the path from its predecessor in the previous row (pixels in parallel).
    Before, every path was walked on its own, a column or a diagonal apart in memory at every step:
    the same sums in the same order (bit for bit), 30 % slower. The step's neighbours come from a
    buffer padded with +inf at both ends, with the penalty to a plane of the other family +inf too,
    so the loop over the planes has no branch. (One function on purpose: a compiled helper closure
    kept numba from loading the kernel from its disk cache, 8 s of compiling in every process.)"""
    import numba

    @numba.njit(parallel=True, cache=True, nogil=True)
    def kernel(cost, n_fronto, p1, p2, n_paths):
        H, W, D = cost.shape
        total = np.zeros((H, W, D), np.float32)
        steps = np.array([[0, 1], [0, -1], [1, 0], [-1, 0], [1, 1], [-1, -1], [1, -1], [-1, 1]])
        inf = np.float32(np.inf)
        # [0, d]: from plane d - 1; [1, d]: from d + 1. float64, as p1 and p2 are: the sums round as before
        pen = np.full((2, D), p1, np.float64)
        pen[0, 0] = inf
        pen[1, D - 1] = inf
        if 0 < n_fronto < D:                                   # no step across the two families
            pen[0, n_fronto] = inf
            pen[1, n_fronto - 1] = inf
        prev_row = np.full((W, D + 2), inf, np.float32)
        cur_row = np.full((W, D + 2), inf, np.float32)
        for k in range(n_paths):
            dy, dx = steps[k, 0], steps[k, 1]
            if dy == 0:
                for y in numba.prange(H):
                    a = np.full(D + 2, inf, np.float32)
                    b = np.full(D + 2, inf, np.float32)
                    x = 0 if dx > 0 else W - 1
                    for d in range(D):
                        a[d + 1] = cost[y, x, d]
                        total[y, x, d] += a[d + 1]
                    for _ in range(W - 1):
                        x += dx
                        low = a[1]
                        for d in range(2, D + 1):
                            low = min(low, a[d])
                        c, t = cost[y, x], total[y, x]
                        for d in range(D):                     # the step, as below
                            best = min(min(a[d + 1], low + p2), min(a[d] + pen[0, d], a[d + 2] + pen[1, d]))
                            v = np.float32(c[d] + best - low)        # rounded as stored, then summed
                            b[d + 1] = v
                            t[d] += v
                        a, b = b, a
                continue
            y = 0 if dy > 0 else H - 1
            for x in numba.prange(W):
                for d in range(D):
                    prev_row[x, d + 1] = cost[y, x, d]
                    total[y, x, d] += prev_row[x, d + 1]
            for _ in range(H - 1):
                y += dy
                for x in numba.prange(W):
                    xp = x - dx
                    if 0 <= xp < W:
                        prev = prev_row[xp]
                        low = prev[1]
                        for d in range(2, D + 1):
                            low = min(low, prev[d])
                        c, t, out = cost[y, x], total[y, x], cur_row[x]
                        for d in range(D):
                            # stay, or jump (p2), or step to the next plane of the same family (p1)
                            best = min(min(prev[d + 1], low + p2), min(prev[d] + pen[0, d], prev[d + 2] + pen[1, d]))
                            v = np.float32(c[d] + best - low)        # rounded as stored, then summed
                            out[d + 1] = v
                            t[d] += v
                    else:                                      # a path starts here
                        for d in range(D):
                            cur_row[x, d + 1] = cost[y, x, d]
                            total[y, x, d] += cur_row[x, d + 1]
                prev_row, cur_row = cur_row, prev_row
        return total
    return kernel


def _plane_numba():
    """ssim_cost of one warped support, quantised (_quantise), in one pass over the pixels (numba):
    the window sums of the warp, of its squares and of its products with the reference as running
    sums, a column's window moving down a row at a time and the row's window along it, with the
    windows wholly inside the support counted alongside. Before it, per plane, a
    compiled pass wrote the squares and products, three OpenCV box filters summed them (4 channels
    each), an erosion found the windows inside and a second compiled pass did the SSIM: 3.3 ms a
    plane at 320 x 240, 1.7 ms on a real pair's planes, against 1.5 and 1.0 ms here.

    Most of a plane falls outside the support on wide baselines (58 % of the voxels of
    square_people's pairs, a third of the rows wholly). So each warped row's span of non-zero
    pixels and its span of valid ones are found first: the column sums are updated only over the
    span of the row entering or leaving the window (elsewhere both are 0: the sums stay as they are,
    exactly), and a row's window slides only over the columns where every row of the window is
    valid (its sums started afresh there); the rest is UNSEEN at once.

    warped: (h, w, 4) float32, the support's Lab and its ones channel (warp); ref, ref_mean,
    ref_var: (h, w, 3) float32 (RefStats); returns (h, w) uint8 (UNSEEN where the k x k window is
    not wholly inside the support). The sums are float64 (float32 running sums would drift over
    the rows); borders are reflected as BORDER_REFLECT does (a reflected pixel is one the window
    holds anyway; the grid is larger than the window). fastmath (the sums are finite): the quantised
    cost one step off in about one voxel in 4 000 against the numpy definition (tests/test_sweep.py)."""
    import numba

    @numba.njit(cache=True, nogil=True, fastmath=True)
    def kernel(warped, ref, ref_mean, ref_var, k, c1, c2, lum_l, w_col, tau):
        H, W = ref.shape[0], ref.shape[1]
        r = k // 2
        inv_n = 1.0 / (k * k)
        # per warped row: [nz_lo, nz_hi) holds its non-zero pixels (outside it the warp is 0 in every
        # channel: the border value), [ok_lo, ok_hi) its valid ones (ones channel > 0.999)
        nz_lo = np.full(H, W, np.int64)
        nz_hi = np.zeros(H, np.int64)
        ok_lo = np.full(H, W, np.int64)
        ok_hi = np.zeros(H, np.int64)
        for row in range(H):
            for x in range(W):
                if warped[row, x, 0] != 0 or warped[row, x, 1] != 0 or warped[row, x, 2] != 0 \
                        or warped[row, x, 3] != 0:
                    nz_lo[row] = min(nz_lo[row], x)
                    nz_hi[row] = x + 1
                if warped[row, x, 3] > 0.999:
                    ok_lo[row] = min(ok_lo[row], x)
                    ok_hi[row] = x + 1
        col = np.zeros((10, W))       # per column, over the window's rows: warp (3), squares (3), products (3), valid
        out = np.full((H, W), UNSEEN, np.uint8)
        for y in range(H):
            if y == 0:                # row 0's window: rows -r .. r (reflected)
                for t in range(k):
                    row = t - r
                    row = -row - 1 if row < 0 else (2 * H - row - 1 if row >= H else row)
                    for x in range(nz_lo[row], nz_hi[row]):
                        w0, w1, w2 = warped[row, x, 0], warped[row, x, 1], warped[row, x, 2]
                        col[0, x] += w0
                        col[1, x] += w1
                        col[2, x] += w2
                        col[3, x] += w0 * w0
                        col[4, x] += w1 * w1
                        col[5, x] += w2 * w2
                        col[6, x] += ref[row, x, 0] * w0
                        col[7, x] += ref[row, x, 1] * w1
                        col[8, x] += ref[row, x, 2] * w2
                        col[9, x] += 1.0 if warped[row, x, 3] > 0.999 else 0.0
            else:                     # row y + r enters the window, row y - r - 1 leaves it
                ra, rb = y + r, y - r - 1
                ra = 2 * H - ra - 1 if ra >= H else ra
                rb = -rb - 1 if rb < 0 else rb
                for x in range(min(nz_lo[ra], nz_lo[rb]), max(nz_hi[ra], nz_hi[rb])):
                    a0, a1, a2 = warped[ra, x, 0], warped[ra, x, 1], warped[ra, x, 2]
                    b0, b1, b2 = warped[rb, x, 0], warped[rb, x, 1], warped[rb, x, 2]
                    col[0, x] += a0 - b0
                    col[1, x] += a1 - b1
                    col[2, x] += a2 - b2
                    col[3, x] += a0 * a0 - b0 * b0
                    col[4, x] += a1 * a1 - b1 * b1
                    col[5, x] += a2 * a2 - b2 * b2
                    col[6, x] += ref[ra, x, 0] * a0 - ref[rb, x, 0] * b0
                    col[7, x] += ref[ra, x, 1] * a1 - ref[rb, x, 1] * b1
                    col[8, x] += ref[ra, x, 2] * a2 - ref[rb, x, 2] * b2
                    col[9, x] += (1.0 if warped[ra, x, 3] > 0.999 else 0.0) - (1.0 if warped[rb, x, 3] > 0.999 else 0.0)
            # the columns whose window can lie wholly inside the support: within every window row's
            # valid span, r columns in from its ends (a window at the image's edge reflects its own
            # columns, so a span reaching the edge keeps it)
            lo, hi = 0, W
            for t in range(k):
                row = y + t - r
                row = -row - 1 if row < 0 else (2 * H - row - 1 if row >= H else row)
                lo = max(lo, 0 if ok_lo[row] == 0 else ok_lo[row] + r)
                hi = min(hi, W if ok_hi[row] == W else ok_hi[row] - r)
            if lo >= hi:
                continue
            # along the row, the same: the window of x = lo (columns lo - r .. lo + r, reflected),
            # then one column in and one out
            s0 = s1 = s2 = s3 = s4 = s5 = s6 = s7 = s8 = s9 = 0.0
            for xx in range(lo - r, lo + r + 1):
                xr = -xx - 1 if xx < 0 else (2 * W - xx - 1 if xx >= W else xx)
                s0 += col[0, xr]
                s1 += col[1, xr]
                s2 += col[2, xr]
                s3 += col[3, xr]
                s4 += col[4, xr]
                s5 += col[5, xr]
                s6 += col[6, xr]
                s7 += col[7, xr]
                s8 += col[8, xr]
                s9 += col[9, xr]
            for x in range(lo, hi):
                if x > lo:
                    a, b = x + r, x - r - 1
                    a = 2 * W - a - 1 if a >= W else a
                    b = -b - 1 if b < 0 else b
                    s0 += col[0, a] - col[0, b]
                    s1 += col[1, a] - col[1, b]
                    s2 += col[2, a] - col[2, b]
                    s3 += col[3, a] - col[3, b]
                    s4 += col[4, a] - col[4, b]
                    s5 += col[5, a] - col[5, b]
                    s6 += col[6, a] - col[6, b]
                    s7 += col[7, a] - col[7, b]
                    s8 += col[8, a] - col[8, b]
                    s9 += col[9, a] - col[9, b]
                if s9 < k * k - 0.5:          # the window is not wholly inside the support
                    continue
                acc = 0.0
                dist2 = 0.0
                for c in range(3):
                    if c == 0:
                        m2, sq2, cross = s0, s3, s6
                    elif c == 1:
                        m2, sq2, cross = s1, s4, s7
                    else:
                        m2, sq2, cross = s2, s5, s8
                    m1 = ref_mean[y, x, c]
                    m2 *= inv_n
                    dist2 += (m1 - m2) * (m1 - m2)
                    v2 = max(sq2 * inv_n - m2 * m2, 0.0)
                    cv = cross * inv_n - m1 * m2
                    if c == 0 and lum_l == 0.0:   # L's mean left out (SweepParams.lightness_mean)
                        acc += (2 * cv + c2) / (ref_var[y, x, c] + v2 + c2)
                    else:                         # luminance term x structure term, one division
                        acc += (2 * m1 * m2 + c1) * (2 * cv + c2) / ((m1 * m1 + m2 * m2 + c1) * (ref_var[y, x, c] + v2 + c2))
                cost = (1.0 - acc / 3) * 0.5
                if w_col > 0.0:          # the windows' mean colours apart (Lab, a and b weighted)
                    cost = (1.0 - w_col) * cost + w_col * min(np.sqrt(dist2) / tau, 1.0)
                cost = min(max(cost, 0.0), 1.0)
                out[y, x] = np.uint8(int(cost * SCALE + 0.5))
        return out
    return kernel


def _planes_last_numba():
    """(D, h, w) uint8 -> (h, w, D) uint8 (numba): numpy's transpose copy of a pair's volume takes
    12.5 ms at 99 x 240 x 320 (every byte written D apart from the last); here 16 columns at a
    time, whose D planes stay in the first-level cache, 6.6 ms (8, 32 or 64 columns, or the
    planes innermost: 7.3-10.6 ms)."""
    import numba

    @numba.njit(cache=True, nogil=True)
    def kernel(per_plane):
        D, H, W = per_plane.shape
        out = np.empty((H, W, D), np.uint8)
        for y in range(H):
            for x0 in range(0, W, 16):
                x1 = min(x0 + 16, W)
                for d in range(D):
                    for x in range(x0, x1):
                        out[y, x, d] = per_plane[d, y, x]
        return out
    return kernel


_volume_kernel = LazyKernel(_volume_numba)
_planes_last_kernel = LazyKernel(_planes_last_numba)
_sgm_kernel = LazyKernel(_sgm_numba)
_plane_kernel = LazyKernel(_plane_numba)
