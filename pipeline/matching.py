"""One ordered pair (reference, support): patch confidences (§3.1.2, Eq. 1) and the pair's
matching map before normalisation (§3.1.3, Eq. 2).

The result keeps everything later stages and viewers need: per reference patch its raw HOG and
colour confidence C(r|I_s, theta), whether it had any candidate in view, and its best candidate
per descriptor; per pixel the Eq. 2 weighted averages of the raw confidences and the share of
weight that came from patches with candidates ("evidence"). Normalising the confidences over the
whole set, weighting descriptors and combining supports happen in aggregate.py, so they can be
changed without recomputing pairs.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from .descriptors import (ImageChannels, color_similarity, hog_similarity, strip_features,
                          window_descriptors, window_valid)
from .geometry import epipoles
from .jit import LazyKernel
from .params import Params
from .sweep import SweepPair
from .patches import (RefStrips, SupportSegments, build_ref_strips, build_support_segments,
                      ref_frames, ref_sample_points, support_sample_points)


@dataclass(frozen=True)
class PatchTable:
    """Reference patches of one pair (P of them) and their best candidates.

    strip, start: (P,) int64 strip id and along start within the strip (samples);
    in_view: (P,) bool, enough of the patch lies inside the reference image to describe it;
    has_candidate: (P,) bool, the corresponding support strip held at least one candidate;
    conf_hog, conf_color: (P,) float32 raw confidences C(r|I_s, theta) (NaN without candidate);
    best_hog_*/best_color_*: (P,) int64 segment, along start and length of the best candidate (-1: none).
    """

    strip: np.ndarray
    start: np.ndarray
    in_view: np.ndarray
    has_candidate: np.ndarray
    conf_hog: np.ndarray
    conf_color: np.ndarray
    best_hog_seg: np.ndarray
    best_hog_start: np.ndarray
    best_hog_len: np.ndarray
    best_color_seg: np.ndarray
    best_color_start: np.ndarray
    best_color_len: np.ndarray


@dataclass(frozen=True)
class PairResult:
    """Matching result of reference `ref` against support `sup` at working resolution (h, w).

    hog_map, color_map: (h, w) float32, Eq. 2 weighted average of the raw confidences of the
    covering patches that had candidates (NaN where none had);
    evidence: (h, w) float32 in [0, 1], share of the Eq. 2 weight from patches with candidates.
    kind: "epipolar" (strips and segments describe the patches) or "homography" (patches are a
    block grid, strip/start in the table are block row/column, H maps reference to support).
    sweep: the pair's cost volume over the reference's depth planes (sweep.SweepPair) when both
    cameras are known and the preset sweeps depths (default), else None.
    plane_diff: (h, w) float32 Lab difference of the support aligned by the homography of the
    pair's matches (peer.plane_difference; NaN where it does not cover the reference), when the
    preset uses that cue (aggregate.plane_weight > 0) and such a homography exists, else None.
    """

    ref: int
    sup: int
    hog_map: np.ndarray
    color_map: np.ndarray
    evidence: np.ndarray
    patches: PatchTable
    strips: RefStrips | None
    segments: SupportSegments | None
    sigma: float
    seconds: float
    kind: str = "epipolar"
    H: np.ndarray | None = None
    sweep: SweepPair | None = None
    plane_diff: np.ndarray | None = None


def patch_length(params: Params) -> int:
    """Patch length L in working pixels, a multiple of the along overlap."""
    ov = params.patches.along_overlap
    return max(ov * 2, int(round(params.patches.patch_frac * params.max_side / ov)) * ov)


def candidate_widths(params: Params, L: int, pair_scale: float) -> np.ndarray:
    """The three candidate lengths (§3.1.1: 'with 3 different widths')."""
    s = float(np.clip(pair_scale, 0.25, 4.0)) if params.patches.scale_from_features else 1.0
    return np.unique(np.maximum(np.round(L * s * np.array(params.patches.candidate_scales)), 4).astype(np.int64))


@dataclass(frozen=True)
class Candidates:
    """Candidate patches of the support strips, sorted by reference strip (C of them).

    strip, seg, start, length: (C,) int64 reference strip, support segment, along start within the
    segment and length (samples); hog: (C, D) float32 unit HOGs; color: (C, B) float32 histograms.
    """

    strip: np.ndarray
    seg: np.ndarray
    start: np.ndarray
    length: np.ndarray
    hog: np.ndarray
    color: np.ndarray


def describe_reference(ch_ref: ImageChannels, st: RefStrips, params: Params):
    """All reference patches of the strips `st`: (patch strip ids, along starts, WindowDescriptors)."""
    dp = params.descriptors
    cells_across, cells_along = dp.hog_cells
    xy_r, strip_of = ref_sample_points(st)
    d_r, n_r = ref_frames(st)
    sf_r = strip_features(ch_ref, xy_r, d_r[strip_of], n_r[strip_of], cells_across, dp.hog_bins, dp.hist_bins)
    p_strip = np.repeat(np.arange(st.n_strips), st.n_win)
    p_j = np.arange(len(p_strip)) - np.repeat(np.concatenate([[0], np.cumsum(st.n_win)[:-1]]), st.n_win)
    p_start = p_j * st.stride
    wr = window_descriptors(sf_r, st.offset[p_strip] + p_start, np.full(len(p_strip), st.L), cells_along,
                            dp.hog_floor, dp.hist_smooth)
    return p_strip, p_start, wr


def describe_candidates(ch_sup: ImageChannels, sg: SupportSegments, L: int, pair_scale: float,
                        params: Params) -> Candidates:
    """Candidates every `step` samples along every support segment, with three widths (§3.1.1)."""
    pp, dp = params.patches, params.descriptors
    cells_across, cells_along = dp.hog_cells
    xy_s, seg_of = support_sample_points(sg)
    sf_s = strip_features(ch_sup, xy_s, sg.along_dir[seg_of], sg.across_dir[seg_of], cells_across,
                          dp.hog_bins, dp.hist_bins)
    step = max(1, int(round(L * pp.candidate_step_frac)))
    c_seg, c_start, c_len = [], [], []
    for width in candidate_widths(params, L, pair_scale):
        n_q = np.maximum((sg.length - width) // step + 1, 0)
        seg = np.repeat(np.arange(len(sg.length)), n_q)
        q = np.arange(len(seg)) - np.repeat(np.concatenate([[0], np.cumsum(n_q)[:-1]]), n_q)
        c_seg.append(seg), c_start.append(q * step), c_len.append(np.full(len(seg), width))
    c_seg, c_start, c_len = (np.concatenate(a).astype(np.int64) for a in (c_seg, c_start, c_len))
    # which windows lie enough inside the support, and their order by strip, before any descriptor:
    # only those kept are described, straight into that order (describing all, then gathering the
    # kept ones twice over, moved 150 MB a pair)
    keep = window_valid(sf_s, sg.offset[c_seg] + c_start, c_len) >= pp.min_valid_candidate
    kept = np.nonzero(keep)[0]
    c_strip = sg.strip[c_seg[kept]]
    order = np.argsort(c_strip, kind="stable")
    idx = kept[order]
    wc = window_descriptors(sf_s, sg.offset[c_seg[idx]] + c_start[idx], c_len[idx], cells_along, dp.hog_floor,
                            dp.hist_smooth)
    return Candidates(c_strip[order], c_seg[idx], c_start[idx], c_len[idx], wc.hog, wc.color)


def match_pair(ref: int, sup: int, ch_ref: ImageChannels, ch_sup: ImageChannels, F: np.ndarray,
               pair_scale: float, params: Params) -> PairResult:
    """Compute C(r|I_s) for all reference patches and the pair's raw matching map."""
    t_start = time.perf_counter()
    pp = params.patches
    L = patch_length(params)
    e_ref, _ = epipoles(F)
    st = build_ref_strips(e_ref, ch_ref.size, L, pp.along_overlap, pp.rows, pp.n_fans)
    p_strip, p_start, wr = describe_reference(ch_ref, st, params)
    hog_r = wr.hog
    in_view = wr.valid >= pp.min_valid_ref
    sg = build_support_segments(F, st, ch_ref.size, ch_sup.size)
    cand = describe_candidates(ch_sup, sg, L, pair_scale, params)
    c_strip, c_seg, c_start, c_len, hog_c, col_c = (cand.strip, cand.seg, cand.start, cand.length, cand.hog,
                                                    cand.color)

    # Eq. 1: confidence = best similarity over the candidates of the corresponding strip.
    P = len(p_strip)
    conf_hog = np.full(P, np.nan, np.float32)
    conf_col = np.full(P, np.nan, np.float32)
    best_h = np.full(P, -1, np.int64)
    best_c = np.full(P, -1, np.int64)
    r_bounds = np.searchsorted(p_strip, np.arange(st.n_strips + 1))
    c_bounds = np.searchsorted(c_strip, np.arange(st.n_strips + 1))
    best_candidates(hog_r, wr.color, in_view, r_bounds, hog_c, col_c, c_bounds, conf_hog, conf_col, best_h, best_c)
    has_cand = best_h >= 0

    def pick(a, idx):
        return np.where(idx >= 0, a[np.maximum(idx, 0)], -1).astype(np.int64)

    table = PatchTable(
        strip=p_strip.astype(np.int64), start=p_start.astype(np.int64), in_view=in_view, has_candidate=has_cand,
        conf_hog=conf_hog, conf_color=conf_col,
        best_hog_seg=pick(c_seg, best_h), best_hog_start=pick(c_start, best_h), best_hog_len=pick(c_len, best_h),
        best_color_seg=pick(c_seg, best_c), best_color_start=pick(c_start, best_c),
        best_color_len=pick(c_len, best_c))
    sigma = patch_sigma(params)
    hog_map, color_map, evidence = splat(st, table, ch_ref.size, sigma, params.aggregate.splat_step)
    return PairResult(ref, sup, hog_map, color_map, evidence, table, st, sg, sigma, time.perf_counter() - t_start)


def best_candidates(hog_r: np.ndarray, col_r: np.ndarray, in_view: np.ndarray, r_bounds: np.ndarray,
                    hog_c: np.ndarray, col_c: np.ndarray, c_bounds: np.ndarray, conf_hog: np.ndarray,
                    conf_col: np.ndarray, best_h: np.ndarray, best_c: np.ndarray) -> None:
    """Eq. 1 for every reference patch: the best similarity over the candidates of its strip,
    HOG (cosine, hog_similarity) and colour (histogram IoU, color_similarity), and which candidate.

    hog_r (P, D), col_r (P, B) float32 reference descriptors, sorted by strip with r_bounds
    (S + 1,) int64 the strips' first rows; hog_c (C, D), col_c (C, B) the candidates, sorted by
    strip with c_bounds. Fills conf_* (P,) float32 and best_* (P,) int64 (the first best, as
    argmax) for patches in view whose strip has candidates; leaves the others untouched.

    Compiled (numba): per strip, numpy made a (patches x candidates x bins) temporary for the
    histogram intersections, the largest cost of a pair after the strip sampling."""
    _eq1_kernel(hog_r, col_r, in_view, r_bounds, hog_c, col_c, c_bounds, conf_hog, conf_col, best_h, best_c)


def _eq1_numba():
    import numba

    @numba.njit(cache=True, nogil=True, fastmath=True)     # the sums may be reordered (SIMD)
    def kernel(hog_r, col_r, in_view, r_bounds, hog_c, col_c, c_bounds, conf_hog, conf_col, best_h, best_c):
        D, B = hog_r.shape[1], col_r.shape[1]
        for s in range(len(r_bounds) - 1):
            c0, c1 = c_bounds[s], c_bounds[s + 1]
            if c1 == c0:
                continue
            for r in range(r_bounds[s], r_bounds[s + 1]):
                if not in_view[r]:
                    continue
                bh, ih, bc, ic = np.float32(-np.inf), -1, np.float32(-np.inf), -1
                for c in range(c0, c1):
                    dot = np.float32(0.0)
                    for d in range(D):
                        dot += hog_r[r, d] * hog_c[c, d]
                    inter = np.float32(0.0)
                    for b in range(B):
                        inter += min(col_r[r, b], col_c[c, b])
                    iou = inter / max(np.float32(2.0) - inter, np.float32(1e-6))
                    if dot > bh:
                        bh, ih = dot, c
                    if iou > bc:
                        bc, ic = iou, c
                conf_hog[r], best_h[r] = bh, ih
                conf_col[r], best_c[r] = bc, ic
    return kernel



_eq1_kernel = LazyKernel(_eq1_numba)


def patch_sigma(params: Params) -> float:
    """Eq. 2: sigma = (max distance from a patch centre to a pixel of the patch) / 3, for the
    nominal L x L patch (strip height equals L at the reference distance)."""
    L = patch_length(params)
    return float(np.hypot(L / 2, L / 2) * params.aggregate.sigma_frac)


def splat(st: RefStrips, table: PatchTable, size: tuple[int, int], sigma: float, step: int = 1
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eq. 2 for every pixel: Gaussian-weighted average over the 9 covering patches.

    Returns hog_map, color_map (h, w) float32 (NaN where no covering patch had a candidate) and
    evidence (h, w) float32. The covering patches are those of patches.iter_covering, found per
    pixel in one compiled pass (numba): numpy needed nine full-image float64 passes with a dozen
    temporaries each.

    step > 1 (ours, a departure for speed; the paper and step 1 evaluate every pixel): the weighted
    sums are evaluated on a grid `step` times coarser, at the points that bilinear resizing maps to
    it, and resized to (h, w) before the division. The maps are smooth at the patches' scale (a
    Gaussian of sigma = 8 px at 640 over patches 24 px long), so a step of 2 changes them by a few
    thousandths, at a quarter of the cost.
    """
    h, w = size
    gh, gw = (h, w) if step <= 1 else (-(-h // step), -(-w // step))
    lut = np.full((st.n_fans, int(st.n_per_fan.max(initial=0)) + 1), -1, np.int64)
    lut[st.fan, st.k] = np.arange(st.n_strips)
    usable = table.in_view
    cand = usable & table.has_candidate
    conf_h = np.where(cand, table.conf_hog, 0.0).astype(np.float64)
    conf_c = np.where(cand, table.conf_color, 0.0).astype(np.float64)
    win_base = np.concatenate([[0], np.cumsum(st.n_win)[:-1]]).astype(np.int64)
    sums = _splat_kernel(
        gh, gw, w / gw, h / gh, float(st.epipole[0]), float(st.epipole[1]), float(st.theta_lo), float(st.dtheta),
        bool(st.circle), int(st.n_fans), st.n_per_fan.astype(np.int64), lut, np.cos(st.theta_c.astype(np.float64)),
        np.sin(st.theta_c.astype(np.float64)), st.t0.astype(np.float64), st.n_win.astype(np.int64), win_base,
        int(st.stride), int(st.L), usable, cand, conf_h, conf_c, 1.0 / (2 * sigma * sigma))
    if (gh, gw) != (h, w):
        import cv2
        sums = cv2.resize(sums, (w, h), interpolation=cv2.INTER_LINEAR)
    w_all, w_cand, s_hog, s_col = (sums[..., k] for k in range(4))
    with np.errstate(invalid="ignore", divide="ignore"):
        has = w_cand > 0
        hog_map = np.where(has, s_hog / w_cand, np.nan).astype(np.float32)
        color_map = np.where(has, s_col / w_cand, np.nan).astype(np.float32)
        evidence = np.where(w_all > 0, w_cand / w_all, 0.0).astype(np.float32)
    return hog_map, color_map, evidence


def _splat_numba():
    import math

    import numba

    @numba.njit(cache=True, nogil=True)
    def kernel(gh, gw, sx, sy, ex, ey, theta_lo, dtheta, circle, n_fans, n_per_fan, lut, cos_c, sin_c, t0, n_win,
               win_base, stride, L, usable, cand, conf_h, conf_c, inv2s2):
        # per grid point: the weights of the usable covering patches, of those with a candidate, and
        # the latter's weighted confidences (HOG, colour); grid point (i, j) is pixel
        # ((j + 0.5) sx - 0.5, (i + 0.5) sy - 0.5), which bilinear resizing maps it to (the pixel itself at sx = 1)
        sums = np.empty((gh, gw, 4), np.float64)
        two_pi = 2.0 * np.pi
        o = 0.0 if circle else 1.0
        n_patches = len(usable)
        n_off = L // stride
        # The Gaussian of the m-th covering patch along a strip, whose centre is m strides back
        # from the nearest: exp(-((d0 + m s)^2 + u^2) a) = exp(-(d0^2 + u^2) a) q^m exp(-m^2 s^2 a),
        # q = exp(-2 d0 s a): two exponentials per strip instead of one per patch.
        tail = np.exp(-(np.arange(n_off) * stride) ** 2 * inv2s2)
        for iy in range(gh):
            y = (iy + 0.5) * sy - 0.5
            for ix in range(gw):
                x = (ix + 0.5) * sx - 0.5
                dx, dy = x - ex, y - ey
                theta = math.atan2(dy, dx)
                rel = theta - theta_lo        # in [-2 pi, 2 pi]: theta_lo is an angle of atan2, or 0
                rel = rel + two_pi if rel < 0.0 else (rel - two_pi if rel >= two_pi else rel)   # = rel % two_pi
                w_all = w_cand = s_hog = s_col = 0.0
                for f in range(n_fans):
                    k = int(math.floor(rel / dtheta - f / n_fans + o))
                    if circle:
                        k = k % n_per_fan[f]
                    if k < 0 or k >= n_per_fan[f]:
                        continue
                    s = lut[f, k]
                    if s < 0:
                        continue
                    t = dx * cos_c[s] + dy * sin_c[s]            # along the strip's axis: r cos(theta - theta_c)
                    u = dy * cos_c[s] - dx * sin_c[s]            # across it: r sin(theta - theta_c)
                    if t < 0:
                        continue
                    j_hi = int(math.floor((t - t0[s]) / stride))
                    d0 = t - (t0[s] + j_hi * stride + L / 2)
                    g = math.exp(-(d0 * d0 + u * u) * inv2s2)
                    q = math.exp(-2.0 * d0 * stride * inv2s2)
                    qm = 1.0
                    for m in range(n_off):
                        j = j_hi - m
                        wgt = g * qm * tail[m]
                        qm *= q
                        if j < 0 or j >= n_win[s]:
                            continue
                        pid = min(win_base[s] + j, n_patches - 1)
                        if usable[pid]:
                            w_all += wgt
                        if cand[pid]:
                            w_cand += wgt
                            s_hog += wgt * conf_h[pid]
                            s_col += wgt * conf_c[pid]
                sums[iy, ix, 0] = w_all
                sums[iy, ix, 1] = w_cand
                sums[iy, ix, 2] = s_hog
                sums[iy, ix, 3] = s_col
        return sums
    return kernel


_splat_kernel = LazyKernel(_splat_numba)