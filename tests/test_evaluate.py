"""Jaccard evaluation (§4.2) on hand-made cases."""

import numpy as np

from pipeline.evaluate import THRESHOLDS, jaccard, jaccard_curve, score_set, static_false_positive_rate


def test_jaccard_hand_made():
    gt = np.zeros((4, 4), np.uint8)
    gt[0, :2] = 255              # two moving pixels
    gt[3, 3] = 128               # don't care
    pred = np.zeros((4, 4), bool)
    pred[0, 0] = pred[1, 0] = pred[3, 3] = True
    # intersection 1, union {(0,0),(0,1),(1,0)} = 3; (3,3) ignored
    assert np.isclose(jaccard(pred, gt), 1 / 3)
    assert jaccard(np.zeros((2, 2), bool), np.zeros((2, 2), np.uint8)) == 1.0


def test_curve_matches_brute_force():
    rng = np.random.default_rng(0)
    prob = rng.random((30, 40)).astype(np.float32)
    gt = np.where(rng.random((30, 40)) < 0.3, 255, 0).astype(np.uint8)
    gt[rng.random((30, 40)) < 0.1] = 128
    curve = jaccard_curve(prob, gt)
    for k in (0, 37, 100, 150, 200):
        assert np.isclose(curve[k], jaccard(prob > THRESHOLDS[k], gt))


def test_score_set_optimises_thresholds():
    gt = np.zeros((10, 10), np.uint8)
    gt[:5] = 255
    good = np.where(gt == 255, 0.9, 0.1).astype(np.float32)
    shifted = np.where(gt == 255, 0.4, 0.2).astype(np.float32)
    sc = score_set({"a": good, "b": shifted}, {"a": gt, "b": gt})
    assert sc.mean_opt_image == 1.0                       # each image has its perfect threshold
    assert sc.per_image_threshold["a"] >= 0.4 or sc.per_image_threshold["a"] < 0.9
    assert 0.2 <= sc.set_threshold < 0.4 and sc.mean_opt_set == 1.0
    assert sc.n_with_motion == 2
    # at the masks' fixed threshold: "good" is right, "shifted" marks nothing
    assert sc.mask_threshold == 0.5 and sc.mean_at_mask == 0.5
    assert score_set({"a": good, "b": shifted}, {"a": gt, "b": gt}, mask_threshold=0.3).mean_at_mask == 1.0


def test_static_false_positive_rate():
    p = np.array([[0.6, 0.4], [0.7, 0.1]])
    assert static_false_positive_rate({"x": p}) == 0.5
    gt = np.array([[255, 0], [0, 0]], np.uint8)
    assert np.isclose(static_false_positive_rate({"x": p}, {"x": gt}), 1 / 3)
