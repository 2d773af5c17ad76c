"""Homography pairs (default preset): point-to-point comparison after alignment.

When one homography H explains the static scene of a pair (same spot, pure rotation, distant or
planar scene), F is undetermined and the paper drops the pair. Yet the epipolar strip then
collapses to the point H gives: 2-D change detection after alignment. We warp the support into
the reference frame and compare each reference patch with the support patches in a small window
around the same place (residual parallax), with the same descriptors and the same Eq. 1 / Eq. 2
machinery as epipolar pairs.

Patches are L x L squares made of 3 x 3 blocks of L/3 pixels, starting every block, so each pixel
is covered by 9 patches, as on epipolar pairs. A block's orientation histogram is one HOG cell
and its colour counts add up to the patch histogram.
"""

from __future__ import annotations

import time

import cv2
import numpy as np

from .descriptors import image_channels_for, smooth_hist
from .params import Params
from .photometric import normalise_aligned

PAD = 2      # blocks of padding so that border pixels are covered by 9 patches too


def _block_features(gx, gy, color_bin, valid, s, nby, nbx, bins, hist_bins):
    """Per block (nby, nbx): orientation histogram (bins), colour counts (hist_bins^2), valid count."""
    h, w = gx.shape
    ys, xs = np.mgrid[0:h, 0:w]
    bid = ((ys // s + PAD) * nbx + (xs // s + PAD)).ravel()
    mag = (np.hypot(gx, gy) * valid).ravel()
    ori = np.mod(np.arctan2(gy, gx), np.pi).ravel() * (bins / np.pi) - 0.5
    b0 = np.floor(ori)
    frac = ori - b0
    b0 = np.mod(b0.astype(np.int64), bins)
    b1 = np.mod(b0 + 1, bins)
    nblk = nby * nbx
    hog = (np.bincount(bid * bins + b0, mag * (1 - frac), nblk * bins)
           + np.bincount(bid * bins + b1, mag * frac, nblk * bins)).reshape(nby, nbx, bins)
    nb = hist_bins * hist_bins
    v = valid.ravel() > 0
    col = np.bincount(bid[v] * nb + color_bin.ravel()[v].astype(np.int64), minlength=nblk * nb).reshape(nby, nbx, nb)
    cnt = np.bincount(bid, valid.ravel().astype(np.float64), nblk).reshape(nby, nbx)
    return hog.astype(np.float32), col.astype(np.float32), cnt


def _patches(hog, col, cnt, s, hog_floor, hist_smooth=False):
    """3 x 3 block patches starting at every block: HOG (Py, Px, 81) unit norm, colour (Py, Px, B)
    normalised, valid share (Py, Px)."""
    nby, nbx = cnt.shape
    py, px = nby - 2, nbx - 2
    cells = np.stack([hog[i:i + py, j:j + px] for i in range(3) for j in range(3)], axis=2)   # (py, px, 9, bins)
    cells = cells + hog_floor / hog.shape[-1] * (s * s)
    h = cells.reshape(py, px, -1)
    h /= np.linalg.norm(h, axis=-1, keepdims=True) + 1e-6
    c = sum(col[i:i + py, j:j + px] for i in range(3) for j in range(3))
    c = c / np.maximum(c.sum(axis=-1, keepdims=True), 1e-6)
    if hist_smooth:
        c = smooth_hist(c)
    v = sum(cnt[i:i + py, j:j + px] for i in range(3) for j in range(3)) / (9 * s * s)
    return h.astype(np.float32), c.astype(np.float32), v


def match_pair_homography(ref: int, sup: int, rgb_ref: np.ndarray, rgb_sup: np.ndarray, H: np.ndarray,
                          params: Params, inliers_ref: np.ndarray | None = None):
    """Eq. 1 / Eq. 2 for a homography pair. Returns a matching.PairResult (kind "homography")."""
    from .matching import PairResult, PatchTable, patch_length, patch_sigma

    t0 = time.perf_counter()
    pp, dp = params.patches, params.descriptors
    L = patch_length(params)
    s = L // 3
    h, w = rgb_ref.shape[:2]
    # support warped into the reference frame: warped(x) = support(H x)
    flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
    warped = cv2.warpPerspective(rgb_sup, H, (w, h), flags=flags, borderMode=cv2.BORDER_REFLECT)
    inside = cv2.warpPerspective(np.ones(rgb_sup.shape[:2], np.uint8), H, (w, h),
                                 flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP, borderValue=0)
    if dp.color_normalise:
        warped = normalise_aligned(rgb_ref, warped, inside)
    nby, nbx = -(-h // s) + 2 * PAD, -(-w // s) + 2 * PAD
    feats = []
    for img, valid in ((rgb_ref, np.ones((h, w), np.float32)), (warped, inside.astype(np.float32))):
        ch = image_channels_for(img, dp)
        blk = _block_features(ch.gx, ch.gy, ch.color_bin, valid, s, nby, nbx, dp.hog_bins, dp.hist_bins)
        feats.append(_patches(*blk, s, dp.hog_floor, dp.hist_smooth))
    (hr, cr, vr), (hs, cs, vs) = feats
    py, px = vr.shape
    in_view = vr >= pp.min_valid_ref
    reached = np.ones((py, px), bool)
    if pp.homography_reach_frac > 0 and inliers_ref is not None:
        reached = _within_reach(inliers_ref, s, (py, px), (h, w), pp.homography_reach_frac * max(h, w))
    r = pp.homography_search
    offsets = [(di, dj) for di in range(-r, r + 1) for dj in range(-r, r + 1)]
    best_h = np.full((py, px), -np.inf, np.float32)
    best_c = np.full((py, px), -np.inf, np.float32)
    arg_h = np.full((py, px), -1, np.int64)
    arg_c = np.full((py, px), -1, np.int64)
    for k, (di, dj) in enumerate(offsets):      # one vectorised comparison of all patches per offset
        ys = slice(max(0, -di), py - max(0, di))
        xs = slice(max(0, -dj), px - max(0, dj))
        ys2 = slice(ys.start + di, ys.stop + di)
        xs2 = slice(xs.start + dj, xs.stop + dj)
        ok = vs[ys2, xs2] >= pp.min_valid_candidate
        sh = np.where(ok, np.sum(hr[ys, xs] * hs[ys2, xs2], axis=-1), -np.inf)
        inter = np.minimum(cr[ys, xs], cs[ys2, xs2]).sum(axis=-1)
        sc = np.where(ok, inter / np.maximum(2.0 - inter, 1e-6), -np.inf)
        better_h = sh > best_h[ys, xs]
        better_c = sc > best_c[ys, xs]
        best_h[ys, xs] = np.where(better_h, sh, best_h[ys, xs])
        arg_h[ys, xs] = np.where(better_h, k, arg_h[ys, xs])
        best_c[ys, xs] = np.where(better_c, sc, best_c[ys, xs])
        arg_c[ys, xs] = np.where(better_c, k, arg_c[ys, xs])
    has = np.isfinite(best_h) & in_view & reached
    conf_h = np.where(has, best_h, np.nan).astype(np.float32)
    conf_c = np.where(has, best_c, np.nan).astype(np.float32)
    rows, cols = np.mgrid[0:py, 0:px]
    minus = np.full(py * px, -1, np.int64)
    table = PatchTable(strip=rows.ravel().astype(np.int64), start=cols.ravel().astype(np.int64),
                       in_view=in_view.ravel(), has_candidate=has.ravel(), conf_hog=conf_h.ravel(),
                       conf_color=conf_c.ravel(), best_hog_seg=np.where(has, arg_h, -1).ravel(),
                       best_hog_start=minus, best_hog_len=minus,
                       best_color_seg=np.where(has, arg_c, -1).ravel(), best_color_start=minus,
                       best_color_len=minus)
    sigma = patch_sigma(params)
    hog_map, color_map, evidence = _splat_grid(conf_h, conf_c, in_view, has, s, (h, w), sigma)
    return PairResult(ref, sup, hog_map, color_map, evidence, table, None, None, sigma,
                      time.perf_counter() - t0, kind="homography", H=H)


def _centre(index, s: int):
    """Pixel coordinate of the centre of the patch whose first block is `index` (padded grid)."""
    return (index - PAD + 1.5) * s - 0.5


def reach_distance(points: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """(h, w) float32: each pixel's distance to the convex hull of `points` ((K, 2) float x, y),
    0 inside. Inside the hull H interpolates what its inliers confirm (the river between two
    matched shores); beyond it H extrapolates, which a plane seen from apart does not survive (the
    ground below a matched facade)."""
    h, w = size
    free = np.full((h, w), 255, np.uint8)
    xy = np.round(points).astype(np.int32)
    ok = (xy[:, 0] >= 0) & (xy[:, 0] < w) & (xy[:, 1] >= 0) & (xy[:, 1] < h)
    free[xy[ok, 1], xy[ok, 0]] = 0
    if ok.sum() >= 3:
        cv2.fillConvexPoly(free, cv2.convexHull(xy[ok]), 0)
    return cv2.distanceTransform(free, cv2.DIST_L2, 5)


def aligned_support(rgb_sup: np.ndarray, H: np.ndarray, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """The support warped into the reference frame by H (x_sup ~ H x_ref): ((h, w, 3) uint8,
    (h, w) float32 coverage)."""
    h, w = size
    flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
    warped = cv2.warpPerspective(rgb_sup, H, (w, h), flags=flags, borderMode=cv2.BORDER_REFLECT)
    inside = cv2.warpPerspective(np.ones(rgb_sup.shape[:2], np.float32), H, (w, h),
                                 flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP, borderValue=0)
    return warped, inside


def _within_reach(points: np.ndarray, s: int, grid: tuple[int, int], size: tuple[int, int], reach: float
                  ) -> np.ndarray:
    """(py, px) bool: the patch centre lies within `reach` px of the convex hull of `points`
    (reach_distance)."""
    h, w = size
    dist = reach_distance(points, size)
    py, px = grid
    cy = np.clip(_centre(np.arange(py), s).round().astype(np.int64), 0, h - 1)
    cx = np.clip(_centre(np.arange(px), s).round().astype(np.int64), 0, w - 1)
    return dist[np.ix_(cy, cx)] <= reach


def _splat_grid(conf_h, conf_c, in_view, has, s, size, sigma):
    """Eq. 2 on the block grid: each pixel averages its 9 covering patches with Gaussian weights."""
    h, w = size
    ys, xs = np.mgrid[0:h, 0:w]
    by, bx = ys // s + PAD, xs // s + PAD                     # block of the pixel (padded grid)
    py, px = conf_h.shape
    acc = {k: np.zeros((h, w)) for k in ("all", "cand", "h", "c")}
    inv = 1.0 / (2 * sigma * sigma)
    for di in range(3):
        for dj in range(3):
            i, j = by - di, bx - dj                           # patch whose top-left block is (i, j)
            ok = (i >= 0) & (i < py) & (j >= 0) & (j < px)
            ic, jc = np.clip(i, 0, py - 1), np.clip(j, 0, px - 1)
            cy, cx = _centre(i, s), _centre(j, s)
            wgt = np.exp(-((ys - cy) ** 2 + (xs - cx) ** 2) * inv) * ok
            wu = wgt * in_view[ic, jc]
            wc = wgt * has[ic, jc]
            acc["all"] += wu
            acc["cand"] += wc
            acc["h"] += wc * np.nan_to_num(conf_h[ic, jc])
            acc["c"] += wc * np.nan_to_num(conf_c[ic, jc])
    with np.errstate(invalid="ignore", divide="ignore"):
        hog_map = np.where(acc["cand"] > 0, acc["h"] / acc["cand"], np.nan)
        color_map = np.where(acc["cand"] > 0, acc["c"] / acc["cand"], np.nan)
        evidence = np.where(acc["all"] > 0, acc["cand"] / acc["all"], 0.0)
    return hog_map.astype(np.float32), color_map.astype(np.float32), evidence.astype(np.float32)
