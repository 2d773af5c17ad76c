"""Which pairs of a large set get full geometry: a cheap screen on a few features per photo.

Full geometry (all SIFT matches, MAGSAC++, the tests of support.py) costs about a second per
unordered pair, and a set of n photos has n(n - 1)/2 of them: 4,950 for 100 photos. Most of them
share nothing (photos taken from opposite sides of an event). The screen matches only the
`n_features` strongest keypoints of every photo against every other photo (one matrix product per
photo) and counts the ratio-test matches per pair; each photo then keeps its `keep` best partners,
so that geometry grows about linearly with n. Pairs left out are rejected as "not compared"; the
set's reconstruction can still give them cameras' geometry when both photos register
(reconstruction.apply_reconstruction). Small sets are not screened (`GeometryParams.screen_above`).

Departure from the paper (its sets have 4-10 photos and every pair is tried).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .features import Features


@dataclass(frozen=True)
class Screen:
    """The screen of a set of n photos.

    shared: (n, n) int32 symmetric, ratio-test matches between the photos' strongest keypoints
    (the smaller of the two directions; 0 on the diagonal); pairs: the unordered pairs (i < j) that
    get full geometry, sorted.
    """

    shared: np.ndarray
    pairs: tuple[tuple[int, int], ...]

    def reason(self, i: int, j: int, n_features: int) -> str:
        """Why pair (i, j) was left out, in words."""
        return (f"not compared: {int(self.shared[i, j])} shared features among the {n_features} strongest of each "
                "photo, fewer than either photo's best partners (the screen of large sets)")


def strongest(f: Features, k: int) -> np.ndarray:
    """(min(k, N), 128) float32 descriptors of the k keypoints with the strongest response
    (all keypoints, in order, when the responses are not known)."""
    if f.response is None or len(f.response) <= k:
        return f.desc[:k]
    return f.desc[np.sort(np.argpartition(-f.response, k - 1)[:k])]


def shared_features(feats: list[Features], n_features: int, ratio: float) -> np.ndarray:
    """(n, n) int32: for each ordered pair, how many of photo i's strongest keypoints find a match
    among photo j's strongest that passes Lowe's ratio test; symmetrised by the minimum.

    One (k, n k) matrix product per photo: n^2 k^2 128 multiply-adds in all (100 photos, k = 256:
    about 80 GFLOP, seconds on two cores)."""
    n = len(feats)
    descs = [strongest(f, n_features) for f in feats]
    k = max((len(d) for d in descs), default=0)
    if k < 2:
        return np.zeros((n, n), np.int32)
    # pad every photo to k rows; a padded row (zeros) is at distance 2 from every unit descriptor
    pad = np.zeros((n, k, descs[0].shape[1] if descs else 128), np.float32)
    valid = np.zeros((n, k), bool)
    for i, d in enumerate(descs):
        pad[i, :len(d)], valid[i, :len(d)] = d, True
    flat = pad.reshape(n * k, -1)
    r2 = ratio * ratio
    count = np.zeros((n, n), np.int32)
    for i in range(n):          # one matrix product per photo (n of them), not per pair
        d2 = (2.0 - 2.0 * (pad[i] @ flat.T)).reshape(k, n, k)            # (k rows of i, photo j, k of j)
        d2 = np.where(valid[None], d2, np.inf)
        two = np.partition(d2, 1, axis=2)[:, :, :2]                       # two nearest in each photo j
        ok = (two[:, :, 0] < r2 * two[:, :, 1]) & valid[i][:, None]
        count[i] = ok.sum(axis=0)
    count[np.arange(n), np.arange(n)] = 0
    return np.minimum(count, count.T)


def screen_pairs(shared: np.ndarray, keep: int) -> Screen:
    """The pairs to compare, from shared_features' (n, n) counts: each photo's `keep` partners
    with the most shared features (ties by index), both ways (a pair is compared when either photo
    keeps the other)."""
    n = len(shared)
    chosen = set()
    for i in range(n):
        others = [j for j in np.lexsort((np.arange(n), -shared[i])) if j != i][:keep]
        chosen.update((min(i, int(j)), max(i, int(j))) for j in others)
    return Screen(shared, tuple(sorted(chosen)))
