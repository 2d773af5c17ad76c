"""A peer baseline (preset `peer-homography`): what a user would try first, side by side.

Not the paper's method and not ours: align each support to the reference by one homography
(SIFT matches + RANSAC), take the colour difference, and the median over the supports. It is
right where the scene is planar or the shots share a spot, and reads parallax as change elsewhere.
`crowdcam bench` and the inspector show it next to `paper` and `default` on the same photos.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import cv2
import numpy as np

from .jit import LazyKernel
from .photometric import normalise_aligned

TAU = 15.0          # Lab distance at which P_dynamic = 1 - 1/e (a monotone map: the Jaccard does not care)


@dataclass(frozen=True)
class PeerPair:
    """Colour difference of reference `ref` and support `sup` aligned by the homography H.

    diff: (h, w) float32 Lab distance after a 5x5 Gaussian blur, NaN where the support does not
    cover the reference; H: (3, 3) float64, x_sup ~ H x_ref.
    """

    ref: int
    sup: int
    diff: np.ndarray
    H: np.ndarray
    seconds: float
    kind: str = "peer"


def difference(ref: int, sup: int, rgb_ref: np.ndarray, rgb_sup: np.ndarray, H: np.ndarray) -> PeerPair:
    """Warp the support into the reference frame by H, match its colours (gain and offset over the
    overlap), and measure the per-pixel Lab distance of the blurred images."""
    t0 = time.perf_counter()
    h, w = rgb_ref.shape[:2]
    flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
    warped = cv2.warpPerspective(rgb_sup, H, (w, h), flags=flags, borderMode=cv2.BORDER_REPLICATE)
    inside = cv2.warpPerspective(np.ones(rgb_sup.shape[:2], np.uint8), H, (w, h),
                                 flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP, borderValue=0)
    warped = normalise_aligned(rgb_ref, warped, inside)

    def lab(img):
        return cv2.cvtColor(cv2.GaussianBlur(img, (5, 5), 0).astype(np.float32) / 255.0, cv2.COLOR_RGB2Lab)
    d = np.linalg.norm(lab(rgb_ref) - lab(warped), axis=2)
    inside = cv2.erode(inside, np.ones((5, 5), np.uint8)) > 0
    return PeerPair(ref, sup, np.where(inside, d, np.nan).astype(np.float32), H, time.perf_counter() - t0)


def plane_difference(ref: int, sup: int, rgb_ref: np.ndarray, rgb_sup: np.ndarray, p_ref: np.ndarray,
                     p_sup: np.ndarray, ransac_px: float, min_inliers: int) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The peer's difference as a cue of our own fusion (aggregate.plane_weight): the homography
    of all the pair's feature matches p_ref, p_sup ((N, 2) float32, the F inliers and outliers
    alike, as the peer fits it: the dominant plane), then `difference`. Returns ((h, w) float32
    diff, (3, 3) H), or (None, None) when no homography has `min_inliers` inliers."""
    from .support import fit_homography
    if len(p_ref) < max(8, min_inliers):
        return None, None
    H, mask = fit_homography(p_ref.astype(np.float32), p_sup.astype(np.float32), ransac_px)
    if H is None or int(mask.sum()) < min_inliers:
        return None, None
    H = H / H[2, 2]
    return difference(ref, sup, rgb_ref, rgb_sup, H).diff, H


P_CLIP = 1e-4             # P_peer clipped to [1e-4, 1 - 1e-4]: its logit within +-9.21


def plane_log_odds(diffs: list[np.ndarray], neutral: float) -> np.ndarray:
    """Static log-odds of the plane-aligned difference, (h, w) float32: the peer's own map
    P_peer = dynamic_from_differences(diffs) (1 - exp(-median / TAU), 0.5 where no support covers
    the pixel) read against the map value at a median difference of `neutral`:
    logit(P_neutral) - logit(P_peer), positive (static) below `neutral`, negative above it,
    P_peer clipped to [1e-4, 1 - 1e-4]. So a pixel no support covers reads as the peer's "no evidence"
    (0.5), mildly static (log 9 at the default neutral): most of a scene does not move.
    diffs: per support (h, w) float32 Lab difference, NaN where it does not cover the pixel."""
    p = np.clip(dynamic_from_differences(diffs).astype(np.float64), P_CLIP, 1.0 - P_CLIP)
    logit_peer = np.log(p / (1.0 - p))
    return (np.log(np.expm1(neutral / TAU)) - logit_peer).astype(np.float32)


def median_difference(diffs: list[np.ndarray]) -> np.ndarray:
    """(h, w) float32 median over the supports that cover a pixel of their differences ((h, w)
    float32 each, NaN where a support does not cover it); NaN where none covers it."""
    # numpy's nanmedian goes through masked arrays for a short axis (60 ms a photo of eight supports at
    # 640), and a sort along the supports' axis took 30: a compiled pass instead, each pixel's covering
    # values sorted in place, the middle one or two averaged in float32 as nanmedian does (the same
    # values bit for bit; tests/test_sweep.py)
    return _median_kernel(np.stack(diffs).astype(np.float32, copy=False))


def _median_numba():
    """median_difference's pass (numba): (S, h, w) float32, NaN where a support does not cover the
    pixel -> (h, w) float32 median of the covering values, NaN where none covers it. A row at a
    time, the supports are inserted into per-pixel sorted columns by compare-exchange (NaN as +inf,
    sorting last), a loop without branches over the row that the compiler vectorises: the insertion
    of sweep._volume_numba, kept apart (a compiled helper shared by two kernels built on first use
    would have to be a global of both, and numba does not cache kernels that call closures)."""
    import numba

    @numba.njit(cache=True, nogil=True)
    def kernel(stack):
        S, H, W = stack.shape
        out = np.empty((H, W), np.float32)
        srt = np.empty((S, W), np.float32)
        carry = np.empty(W, np.float32)
        n = np.empty(W, np.int64)
        inf = np.float32(np.inf)
        two = np.float32(2.0)
        for y in range(H):
            n[:] = 0
            for s in range(S):
                v = stack[s, y]
                for x in range(W):
                    seen = v[x] == v[x]
                    carry[x] = v[x] if seen else inf
                    n[x] += seen
                for k in range(s):
                    row = srt[k]
                    for x in range(W):
                        a, b = row[x], carry[x]
                        row[x] = min(a, b)
                        carry[x] = max(a, b)
                srt[s] = carry
            for x in range(W):
                m = n[x]
                out[y, x] = (srt[(m - 1) // 2, x] + srt[m // 2, x]) / two if m > 0 else np.float32(np.nan)
        return out
    return kernel


_median_kernel = LazyKernel(_median_numba)


def dynamic_from_differences(diffs: list[np.ndarray]) -> np.ndarray:
    """Median over the supports that cover a pixel, mapped to (h, w) float32 P_dynamic in [0, 1]
    (1 - exp(-d / TAU)); 0.5 where no support covers it (no evidence)."""
    med = median_difference(diffs)
    p = 1.0 - np.exp(-np.nan_to_num(med, nan=0.0) / TAU)
    return np.where(np.isnan(med), 0.5, p).astype(np.float32)
