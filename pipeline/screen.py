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

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from .features import Features
from .jit import LazyKernel


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


def shared_features(feats: list[Features], n_features: int, ratio: float, threads: int = 1) -> np.ndarray:
    """(n, n) int32: for each ordered pair, how many of photo i's strongest keypoints find a match
    among photo j's strongest that passes Lowe's ratio test; symmetrised by the minimum.

    One (k, (n - i - 1) k) matrix product per photo i, against the photos after it: a block's
    products serve both directions (i's keypoints in j, row by row; j's in i, column by column), so
    n^2 k^2 128 / 2 multiply-adds in all (100 photos, k = 256: about 80 GFLOP). The two nearest per
    row and per column come from one compiled pass over the block (_two_smallest_numba), the photos
    in `threads` threads (the run's workers: BLAS's products and the compiled pass let go of the
    GIL). Before, every photo's product ran against all the others, and a
    partition per direction found the two nearest: 7.4 s on a hundred photos in the main process,
    the pool idle."""
    n = len(feats)
    descs = [strongest(f, n_features) for f in feats]
    k = max((len(d) for d in descs), default=0)
    if k < 2:
        return np.zeros((n, n), np.int32)
    pad = np.zeros((n, k, descs[0].shape[1] if descs else 128), np.float32)
    valid = np.zeros((n, k), bool)
    for i, d in enumerate(descs):
        pad[i, :len(d)], valid[i, :len(d)] = d, True
    flat_t = np.ascontiguousarray(pad.reshape(n * k, -1).T)       # (128, n k): BLAS's fastest layout here
    r2 = np.float32(ratio * ratio)
    count = np.zeros((n, n), np.int32)

    def block(i: int) -> None:
        if i < n - 1:
            dots = pad[i] @ flat_t[:, (i + 1) * k:]                   # (k of i, (n - i - 1) k of the others)
            _two_smallest_kernel(dots, valid[i], valid[i + 1:], k, r2, count[i, i + 1:], count[i + 1:, i])
    with ThreadPoolExecutor(max(1, threads)) as pool:
        list(pool.map(block, range(n)))
    return np.minimum(count, count.T)


def _two_smallest_numba():
    """Ratio-test counts from one block of products (numba): dots (k, m k) float32 between photo
    i's k rows and the k rows of each of m photos; valid_i (k,), valid_j (m, k) bool. Adds to
    row_count[j] the rows of i whose two nearest in photo j pass the test and to col_count[j] the
    rows of photo j whose two nearest in i do. Distances are squared, 2 - 2 a.b in float32 as
    numpy computes them; padded rows count as infinitely far."""
    import numba

    @numba.njit(cache=True, nogil=True)
    def kernel(dots, valid_i, valid_j, k, r2, row_count, col_count):
        m = valid_j.shape[0]
        inf = np.float32(np.inf)
        two, neg2 = np.float32(2.0), np.float32(-2.0)
        col1 = np.empty(k, np.float32)
        col2 = np.empty(k, np.float32)
        for j in range(m):
            col1[:] = inf
            col2[:] = inf
            rows = 0
            for a in range(k):
                if not valid_i[a]:
                    continue
                best, second = inf, inf
                for b in range(k):
                    if not valid_j[j, b]:
                        continue
                    v = two + neg2 * dots[a, j * k + b]
                    if v < best:
                        second, best = best, v
                    elif v < second:
                        second = v
                    if v < col1[b]:
                        col2[b], col1[b] = col1[b], v
                    elif v < col2[b]:
                        col2[b] = v
                if best < r2 * second:
                    rows += 1
            cols = 0
            for b in range(k):
                if col1[b] < r2 * col2[b]:
                    cols += 1
            row_count[j] += rows
            col_count[j] += cols
    return kernel


_two_smallest_kernel = LazyKernel(_two_smallest_numba)


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
