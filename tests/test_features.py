"""features.py: the mutual ratio-test matcher's compiled pass against its numpy definition."""

import numpy as np

from pipeline.features import _two_nearest


def two_nearest_numpy(a, b, chunk):
    """The definition: all distances (BLAS's products chunk by chunk, as the matcher asks for them:
    a product of one row takes another path, with other last bits), then the two smallest and the
    first argmin per row and column."""
    d = np.vstack([2.0 - 2.0 * (a[s:s + chunk] @ b.T) for s in range(0, len(a), chunk)])
    row_d, col_d = np.sort(d, axis=1)[:, :2], np.sort(d, axis=0)[:2].T
    return np.argmin(d, axis=1), row_d, np.argmin(d, axis=0), col_d


def unit_rows(rng, n, dim=16):
    x = rng.standard_normal((n, dim)).astype(np.float32)
    return x / np.linalg.norm(x, axis=1, keepdims=True)


def test_two_nearest_equals_its_definition_across_chunks_and_ties():
    rng = np.random.default_rng(3)
    a, b = unit_rows(rng, 301), unit_rows(rng, 157)
    a[40] = a[7]                    # a tie between rows for every column's nearest
    b[20] = b[90]                   # and between columns for the rows' nearest
    for chunk in (2048, 64, 1):     # one chunk, several, and chunks of one row
        want = two_nearest_numpy(a, b, chunk)
        got = _two_nearest(a, b, chunk=chunk)
        for g, w in zip(got, want):
            assert g.dtype == w.dtype and np.array_equal(g, w)
