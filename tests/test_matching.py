"""The compiled steps of a pair (matching.py) against their plain numpy definitions."""

import numpy as np
import pytest

from pipeline.descriptors import color_similarity, hog_similarity
from pipeline.matching import PatchTable, best_candidates, splat
from pipeline.patches import build_ref_strips, iter_covering


def _unit(a):
    return (a / np.linalg.norm(a, axis=1, keepdims=True)).astype(np.float32)


def _hist(a):
    return (a / a.sum(axis=1, keepdims=True)).astype(np.float32)


def test_eq1_is_the_best_similarity_over_the_strips_candidates():
    rng = np.random.default_rng(0)
    P, C, S = 60, 90, 7
    p_strip = np.sort(rng.integers(0, S, P))
    c_strip = np.sort(rng.integers(0, S - 1, C))          # the last strip has no candidate
    hog_r, hog_c = _unit(rng.random((P, 81))), _unit(rng.random((C, 81)))
    col_r, col_c = _hist(rng.random((P, 20)) ** 4), _hist(rng.random((C, 20)) ** 4)
    in_view = rng.random(P) > 0.2
    r_b, c_b = np.searchsorted(p_strip, np.arange(S + 1)), np.searchsorted(c_strip, np.arange(S + 1))
    conf_h, conf_c = np.full(P, np.nan, np.float32), np.full(P, np.nan, np.float32)
    best_h, best_c = np.full(P, -1, np.int64), np.full(P, -1, np.int64)
    best_candidates(hog_r, col_r, in_view, r_b, hog_c, col_c, c_b, conf_h, conf_c, best_h, best_c)
    for p in range(P):
        c0, c1 = c_b[p_strip[p]], c_b[p_strip[p] + 1]
        if not in_view[p] or c1 == c0:
            assert best_h[p] == -1 and np.isnan(conf_h[p])
            continue
        sh = hog_similarity(hog_r[p:p + 1], hog_c[c0:c1])[0]
        sc = color_similarity(col_r[p:p + 1], col_c[c0:c1])[0]
        assert best_h[p] == c0 + sh.argmax() and conf_h[p] == pytest.approx(sh.max(), abs=1e-6)
        assert best_c[p] == c0 + sc.argmax() and conf_c[p] == pytest.approx(sc.max(), abs=1e-6)


def _random_table(epipole, size, L, seed):
    """Strips around an epipole and a patch table with independent random confidences: (strips,
    table, Eq. 2's sigma for patches of length L)."""
    st = build_ref_strips(np.array([*epipole, 1.0]), size, L, 3, 9, 3)
    P = int(st.n_win.sum())
    rng = np.random.default_rng(seed)
    table = PatchTable(np.zeros(P, np.int64), np.zeros(P, np.int64), rng.random(P) > 0.1, rng.random(P) > 0.3,
                       rng.random(P).astype(np.float32), rng.random(P).astype(np.float32),
                       *(np.zeros(P, np.int64),) * 6)
    return st, table, np.hypot(L / 2, L / 2) / 3


@pytest.mark.parametrize("epipole", [(70.0, 40.0), (-400.0, 90.0)])   # inside (a full circle), outside
def test_splat_is_eq2_over_the_covering_patches(epipole):
    size = (90, 120)
    st, table, sigma = _random_table(epipole, size, 12, 1)
    hog_map, color_map, evidence = splat(st, table, size, sigma)
    # the definition, pixel by pixel over iter_covering's nine (fan, offset) passes
    n = size[0] * size[1]
    w_all, w_cand, s_h, s_c = np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n)
    cand = table.in_view & table.has_candidate
    for pid, ok, d2 in iter_covering(st, size):
        wgt = np.exp(-d2 / (2 * sigma * sigma)) * ok
        w_all += wgt * table.in_view[pid]
        w_cand += wgt * cand[pid]
        s_h += wgt * cand[pid] * np.where(cand, table.conf_hog, 0)[pid]
        s_c += wgt * cand[pid] * np.where(cand, table.conf_color, 0)[pid]
    with np.errstate(invalid="ignore", divide="ignore"):
        ref_h = np.where(w_cand > 0, s_h / w_cand, np.nan).reshape(size)
        ref_e = np.where(w_all > 0, w_cand / w_all, 0).reshape(size)
    assert np.array_equal(np.isnan(hog_map), np.isnan(ref_h))
    np.testing.assert_allclose(hog_map, ref_h, atol=1e-5)
    np.testing.assert_allclose(evidence, ref_e, atol=1e-5)
    assert np.nanmax(color_map) <= 1 and (evidence > 0).mean() > 0.5


@pytest.mark.parametrize("epipole", [(150.0, 100.0), (-900.0, 200.0)])
def test_splat_on_a_coarser_grid_is_close_to_every_pixel(epipole):
    """aggregate.splat_step = 2: the weighted sums on a grid twice as coarse, resized before the
    division, give the full-size maps within about a hundredth (the patches' Gaussians are wide),
    the same pixels without a candidate, and a quarter of the kernel's work."""
    size = (241, 320)                                       # an odd height: the grid does not divide it
    st, table, sigma = _random_table(epipole, size, 24, 2)
    fine, coarse = splat(st, table, size, sigma), splat(st, table, size, sigma, 2)
    for a, b in zip(fine, coarse):
        assert b.shape == size and b.dtype == np.float32
        assert (np.isnan(a) != np.isnan(b)).mean() < 1e-3
        both = ~np.isnan(a) & ~np.isnan(b)
        assert np.abs(a - b)[both].mean() < 0.015          # (independent random confidences: the worst case)
