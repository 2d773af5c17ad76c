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


def slanted_pair(size=240, seed=3):
    """A blob texture (h, w, 3) uint8 and the same texture on a plane turned ~65 deg away, squeezed
    4x across (what a wide-apart phone sees of the ground), with the homography between them."""
    import cv2
    rng = np.random.default_rng(seed)
    noise = cv2.GaussianBlur(rng.random((size, size, 3)).astype(np.float32), (0, 0), 3)
    noise = (noise - noise.min()) / (noise.max() - noise.min())
    flat = (noise * 255).astype(np.uint8)
    src = np.float32([[0, 0], [size, 0], [size, size], [0, size]])
    dst = np.float32([[90, 10], [150, 30], [150, 210], [90, 230]])   # squeezed to a quarter and foreshortened
    H = cv2.getPerspectiveTransform(src, dst)
    return flat, cv2.warpPerspective(flat, H, (size, size), flags=cv2.INTER_AREA), H


def test_affine_simulation_matches_a_slanted_surface_that_plain_sift_barely_does():
    """features.detect(affine_tilts=2) (ASIFT): more correct matches of a plane seen at a slant, and
    never more keypoints than asked for."""
    from pipeline.features import detect, match

    flat, slanted, H = slanted_pair()

    def correct(tilts):
        a, b = detect(flat, 4000, 0.02, tilts), detect(slanted, 4000, 0.02, tilts)
        m = match(a, b, 0.8)
        mapped = np.c_[a.xy[m[:, 0]], np.ones(len(m))] @ H.T
        err = np.linalg.norm(mapped[:, :2] / mapped[:, 2:] - b.xy[m[:, 1]], axis=1)
        return int(np.sum(err < 2.0)), len(a.xy)

    plain, _ = correct(0)
    simulated, n = correct(2)
    assert simulated >= 3 * max(plain, 5), (plain, simulated)
    capped = detect(flat, 300, 0.02, 2)
    assert len(capped.xy) == 300 < n and capped.desc.shape == (300, 128)
