"""Jaccard evaluation against ground-truth masks (§4.2, Table 1).

Ground truth: (H, W) uint8, 0 static, 255 moving, 128 don't care (excluded from both sets).
Thresholds are optimised per image and per set, as in the paper (after the Berkeley protocol).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

THRESHOLDS = np.linspace(0.0, 1.0, 201)    # a pixel is dynamic when P_dynamic > threshold


def jaccard(pred: np.ndarray, gt: np.ndarray) -> float:
    """Intersection over union of a boolean prediction (H, W) and a ground-truth mask.

    Pixels marked 128 are ignored. Both empty -> 1.0 (nothing to find, nothing found).
    """
    care = gt != 128
    g = (gt == 255) & care
    p = pred.astype(bool) & care
    union = np.count_nonzero(g | p)
    return 1.0 if union == 0 else np.count_nonzero(g & p) / union


def jaccard_curve(prob: np.ndarray, gt: np.ndarray, thresholds: np.ndarray = THRESHOLDS) -> np.ndarray:
    """Jaccard of (prob > t) for every threshold t, (T,) float64, in one pass via histograms."""
    care = gt != 128
    v = prob[care].astype(np.float64)
    g = gt[care] == 255
    # count of positives / negatives with prob > t for every t
    edges = np.concatenate([thresholds, [np.inf]])
    idx = np.searchsorted(thresholds, v, side="left")          # number of thresholds strictly below v
    pos = np.bincount(idx[g], minlength=len(edges))
    neg = np.bincount(idx[~g], minlength=len(edges))
    # prob > t_i  <=>  idx > i
    above_pos = np.cumsum(pos[::-1])[::-1]
    above_neg = np.cumsum(neg[::-1])[::-1]
    tp = above_pos[1:len(thresholds) + 1]
    fp = above_neg[1:len(thresholds) + 1]
    n_gt = g.sum()
    union = n_gt + fp
    with np.errstate(invalid="ignore", divide="ignore"):
        j = np.where(union > 0, tp / np.maximum(union, 1), 1.0)
    return j


@dataclass(frozen=True)
class SetScore:
    """Table 1 row: mean and std of the Jaccard with the threshold optimised per image / per set."""

    per_image: dict[str, float]
    per_image_threshold: dict[str, float]
    mean_opt_image: float
    std_opt_image: float
    set_threshold: float
    per_image_at_set: dict[str, float]
    mean_opt_set: float
    std_opt_set: float
    n_images: int
    n_with_motion: int
    mask_threshold: float = 0.5
    mean_at_mask: float = float("nan")     # at mask_threshold, the one a user's masks are cut at

    def to_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


def score_set(probs: dict[str, np.ndarray], gts: dict[str, np.ndarray], mask_threshold: float = 0.5) -> SetScore:
    """Evaluate maps against ground truth for the stems present in both: the paper's Jaccard with
    the threshold optimised per image and per set (§4.2), and the mean Jaccard at `mask_threshold`,
    the fixed threshold the written masks use (no ground truth chooses it for a user).

    Images whose ground truth has no moving pixel are left out of the Jaccard means (there is no
    region to find; use `static_false_positive_rate` for them) unless no image has motion.
    """
    stems = [s for s in probs if s in gts]
    if not stems:
        raise ValueError("no image has both a map and a ground-truth mask")
    motion = [s for s in stems if np.any(gts[s] == 255)]
    use = motion or stems
    curves = {s: jaccard_curve(probs[s], gts[s]) for s in use}
    best = {s: int(np.argmax(c)) for s, c in curves.items()}
    per_image = {s: float(curves[s][best[s]]) for s in use}
    mean_curve = np.mean([curves[s] for s in use], axis=0)
    t_set = int(np.argmax(mean_curve))
    at_set = {s: float(curves[s][t_set]) for s in use}
    return SetScore(per_image=per_image, per_image_threshold={s: float(THRESHOLDS[best[s]]) for s in use},
                    mean_opt_image=float(np.mean(list(per_image.values()))),
                    std_opt_image=float(np.std(list(per_image.values()))),
                    set_threshold=float(THRESHOLDS[t_set]), per_image_at_set=at_set,
                    mean_opt_set=float(np.mean(list(at_set.values()))),
                    std_opt_set=float(np.std(list(at_set.values()))),
                    n_images=len(stems), n_with_motion=len(motion), mask_threshold=float(mask_threshold),
                    mean_at_mask=float(np.mean([jaccard(probs[s] > mask_threshold, gts[s]) for s in use])))


def static_false_positive_rate(probs: dict[str, np.ndarray], gts: dict[str, np.ndarray] | None = None,
                               threshold: float = 0.5) -> float:
    """Share of static pixels (gt == 0, or all pixels without gt) with P_dynamic > threshold."""
    num = den = 0
    for s, p in probs.items():
        mask = (gts[s] == 0) if gts is not None and s in gts else np.ones(p.shape, bool)
        num += np.count_nonzero(p[mask] > threshold)
        den += np.count_nonzero(mask)
    return num / den if den else 0.0
