"""Why is a pixel dynamic? The evidence behind reference patches of an epipolar pair.

For chosen reference patches (or the patches covering chosen pixels), every candidate in the
corresponding support strip with its HOG and colour similarity, and the best ones (Eq. 1). The
numbers come from the same functions as matching.match_pair, run on just the strips involved, so
they equal the confidences the pair's result holds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .descriptors import ImageChannels, color_similarity, hog_similarity
from .matching import PairResult, describe_candidates, describe_reference, patch_length
from .params import Params
from .patches import build_support_segments, iter_covering, ref_patch_quads, subset_strips, support_quads


@dataclass(frozen=True)
class PatchEvidence:
    """One reference patch and its candidates in the support.

    patch: index into the pair's PatchTable; ref_quad: (4, 2) float32 corners in the reference;
    cand_quads: (C, 4, 2) float32 corners in the support; sim_hog, sim_color: (C,) float32;
    best_hog, best_color: index of the best candidate per descriptor (-1 without candidates).
    """

    patch: int
    ref_quad: np.ndarray
    cand_quads: np.ndarray
    sim_hog: np.ndarray
    sim_color: np.ndarray
    best_hog: int
    best_color: int


def patches_at(pair: PairResult, points: np.ndarray) -> list[np.ndarray]:
    """For (N, 2) reference pixels, the ids of the patches that cover each (up to 9)."""
    ids: list[list[int]] = [[] for _ in range(len(points))]
    for pid, ok, _ in iter_covering(pair.strips, (0, 0), points=np.asarray(points, np.float64)):
        for n in np.nonzero(ok)[0]:
            ids[n].append(int(pid[n]))
    return [np.array(sorted(set(i)), np.int64) for i in ids]


def explain_patches(pair: PairResult, ch_ref: ImageChannels, ch_sup: ImageChannels, F: np.ndarray,
                    pair_scale: float, params: Params, patch_ids: np.ndarray) -> list[PatchEvidence]:
    """Candidates and similarities for the given patches of an epipolar pair."""
    if pair.kind != "epipolar":
        raise ValueError("explain_patches needs an epipolar pair")
    table, st = pair.patches, pair.strips
    patch_ids = np.asarray(patch_ids, np.int64)
    strips = np.unique(table.strip[patch_ids])
    sub = subset_strips(st, strips)
    p_strip, p_start, wr = describe_reference(ch_ref, sub, params)
    sg = build_support_segments(F, sub, ch_ref.size, ch_sup.size)
    cand = describe_candidates(ch_sup, sg, patch_length(params), pair_scale, params)
    out = []
    for pid in patch_ids:
        s_local = int(np.searchsorted(strips, table.strip[pid]))
        row = np.nonzero((p_strip == s_local) & (p_start == table.start[pid]))[0][0]
        sel = np.nonzero(cand.strip == s_local)[0]
        ref_quad = ref_patch_quads(st, table.strip[pid:pid + 1], table.start[pid:pid + 1])[0]
        if len(sel) == 0 or not table.in_view[pid]:
            out.append(PatchEvidence(int(pid), ref_quad, np.zeros((0, 4, 2), np.float32), np.zeros(0, np.float32),
                                     np.zeros(0, np.float32), -1, -1))
            continue
        sh = hog_similarity(wr.hog[row:row + 1], cand.hog[sel])[0]
        sc = color_similarity(wr.color[row:row + 1], cand.color[sel])[0]
        quads = support_quads(sg, cand.seg[sel], cand.start[sel], cand.length[sel])
        out.append(PatchEvidence(int(pid), ref_quad, quads, sh.astype(np.float32), sc.astype(np.float32),
                                 int(np.argmax(sh)), int(np.argmax(sc))))
    return out
