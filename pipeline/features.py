"""SIFT features and mutual ratio-test matching (OpenCV)."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class Features:
    """Keypoints of one photo at working resolution.

    xy: (N, 2) float32 pixel positions; size: (N,) float32 keypoint diameters;
    desc: (N, 128) float32 RootSIFT descriptors.
    """

    xy: np.ndarray
    size: np.ndarray
    desc: np.ndarray


def detect(rgb: np.ndarray, n_features: int) -> Features:
    """SIFT on (h, w, 3) uint8 RGB. Descriptors are RootSIFT (Arandjelovic & Zisserman 2012)."""
    gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    sift = cv2.SIFT_create(nfeatures=n_features)
    kps, desc = sift.detectAndCompute(gray, None)
    if desc is None or len(kps) == 0:
        return Features(np.zeros((0, 2), np.float32), np.zeros(0, np.float32), np.zeros((0, 128), np.float32))
    desc = desc / (np.abs(desc).sum(axis=1, keepdims=True) + 1e-7)
    desc = np.sqrt(desc).astype(np.float32)
    xy = np.array([k.pt for k in kps], dtype=np.float32)
    size = np.array([k.size for k in kps], dtype=np.float32)
    return Features(xy, size, desc)


def match(a: Features, b: Features, ratio: float) -> np.ndarray:
    """Mutual nearest neighbours that pass the ratio test in both directions.

    RootSIFT descriptors have unit L2 norm, so squared distances are 2 - 2 a.b and one
    matrix product gives both directions' two nearest neighbours.
    Returns (M, 2) int64 indices into a and b.
    """
    if len(a.xy) < 2 or len(b.xy) < 2:
        return np.zeros((0, 2), np.int64)
    dist = np.sqrt(np.maximum(2.0 - 2.0 * (a.desc @ b.desc.T), 0.0))     # (Na, Nb)

    def one_way(d: np.ndarray) -> np.ndarray:
        two = np.partition(d, 1, axis=1)[:, :2]
        best = np.argmin(d, axis=1)
        return np.where(two[:, 0] < ratio * two[:, 1], best, -1)

    ab, ba = one_way(dist), one_way(dist.T)
    ia = np.nonzero(ab >= 0)[0]
    ib = ab[ia]
    keep = ba[ib] == ia
    return np.stack([ia[keep], ib[keep]], axis=1).astype(np.int64)
