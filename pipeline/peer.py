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


def dynamic_from_differences(diffs: list[np.ndarray]) -> np.ndarray:
    """Median over the supports that cover a pixel, mapped to (h, w) float32 P_dynamic in [0, 1]
    (1 - exp(-d / TAU)); 0.5 where no support covers it (no evidence)."""
    with np.errstate(all="ignore"):
        import warnings
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)     # all-NaN columns: nothing covers the pixel
            med = np.nanmedian(np.stack(diffs), axis=0)
    p = 1.0 - np.exp(-np.nan_to_num(med, nan=0.0) / TAU)
    return np.where(np.isnan(med), 0.5, p).astype(np.float32)
