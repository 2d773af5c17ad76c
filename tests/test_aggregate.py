"""Aggregation properties stated in §3.2 and the Eq. 2 normalisation."""

import numpy as np

from pipeline.aggregate import Normaliser, combine, match_probability, remap
from pipeline.params import AggregateParams, DescriptorParams

AP = AggregateParams()
NO_REMAP = AggregateParams(remap=(0.0, 1.0))


def static(ps, ap=NO_REMAP):
    return 1.0 - combine([np.full((1, 1), p) for p in ps], ap)[0, 0]


def test_half_is_neutral():
    for p in (0.2, 0.6, 0.9):
        assert np.isclose(static([p, 0.5]), static([p]), atol=1e-6)
    assert np.isclose(static([0.5, 0.5, 0.5]), 0.5)


def test_agreement_strengthens():
    assert static([0.7, 0.8]) > 0.8
    assert static([0.3, 0.2]) < 0.2


def test_disagreement_lies_between():
    s = static([0.8, 0.3])
    assert 0.3 < s < 0.8
    assert np.isclose(static([0.8, 0.2]), 0.5, atol=1e-6)


def test_product_rule_matches_the_formula():
    ps = [0.9, 0.6, 0.35]
    num = np.prod(ps)
    assert np.isclose(static(ps), num / (num + np.prod([1 - p for p in ps])), atol=1e-6)


def test_remap_bounds_the_influence_of_extremes():
    assert np.isclose(remap(np.array(0.0), 0.3, 0.7), 0.3) and np.isclose(remap(np.array(1.0), 0.3, 0.7), 0.7)
    # one certain "no match" cannot outvote two confident matches after remapping
    assert static([0.0, 1.0, 1.0], AP) > 0.5


def test_dynamic_is_the_complement():
    p = combine([np.array([[0.8]]), np.array([[0.7]])], AP)[0, 0]
    assert 0 <= p <= 1 and np.isclose(p, 1 - static([0.8, 0.7], AP))


def test_match_probability_normalises_and_weights():
    norm = Normaliser(hog=(0.5, 1.0), color=(0.0, 0.5))
    dp = DescriptorParams()
    hog = np.array([[0.5, 1.0, 0.75]])
    col = np.array([[0.5, 0.0, 0.25]])
    ev = np.ones((1, 3))
    p = match_probability(hog, col, ev, norm, dp, AP)
    assert np.allclose(p, [[(2 * 0 + 1) / 3, (2 * 1 + 0) / 3, (2 * 0.5 + 0.5) / 3]])


def test_no_evidence_is_no_match_in_the_paper_and_neutral_otherwise():
    norm = Normaliser(hog=(0.0, 1.0), color=(0.0, 1.0))
    nan = np.full((1, 1), np.nan)
    ev = np.zeros((1, 1))
    dp = DescriptorParams()
    assert match_probability(nan, nan, ev, norm, dp, AP)[0, 0] == 0.0
    assert match_probability(nan, nan, ev, norm, dp, AggregateParams(no_evidence="neutral"))[0, 0] == 0.5


def test_normaliser_uses_the_range_over_all_pairs():
    n = Normaliser.from_confidences([np.array([0.2, np.nan, 0.9]), np.array([0.4])],
                                    [np.array([0.1]), np.array([0.6, 0.3])])
    assert n.hog == (0.2, 0.9) and n.color == (0.1, 0.6)


def test_support_sweep_equals_combining_each_prefix():
    from pipeline.aggregate import cumulative_dynamic
    rng = np.random.default_rng(0)
    probs = [rng.random((6, 7)).astype(np.float32) for _ in range(5)]
    sweep = list(cumulative_dynamic(probs, AP))
    assert len(sweep) == 5
    for k, m in enumerate(sweep, start=1):
        assert np.array_equal(m, combine(probs[:k], AP))
