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


@dataclass(frozen=True)
class PixelEvidence:
    """Why reference pixel `xy` got its P(x|I_sup): what the support was searched along, and the
    covering patch that weighs most in Eq. 2 (the one whose centre is nearest) with its best
    candidates.

    kind: "epipolar" or "homography"; xy: (2,) float working-resolution reference pixel;
    evidence: share of the Eq. 2 weight at xy from patches that had candidates (0 = no evidence);
    line: (3,) float64 epipolar line l = F x in the support (a x + b y + c = 0), epipolar pairs;
    point: (2,) float64 H x in the support, homography pairs; window: (4, 2) float32 the
    homography search window (the patch grown by the parallax search) in the support;
    patch: the dominant patch's evidence or None when no patch covers xy. For homography pairs
    its candidates are just the best HOG and best colour ones (sims NaN for the other cue),
    read from the pair's table.
    Swept pairs (sweep.py) add: strip: (2, 2) float64 the part of the epipolar line the
    reference's depth range allows (near to far, the bounded strip) in the support; depth_point:
    where the depth all supports agreed on puts the pixel in the support; depth: that depth
    (reference camera, the reconstruction's units; inf for the plane at infinity; NaN for a pencil
    without cameras, pencil.py, whose strip is the part of the line its hypotheses span); cost: this
    support's colour-SSIM cost there (NaN: it does not see it); curve: (D,) its cost at every
    plane from near to far, and fused_curve: (D,) the fused cost (both NaN where unseen).
    """

    ref: int
    sup: int
    kind: str
    xy: np.ndarray
    evidence: float
    n_covering: int
    patch: PatchEvidence | None
    line: np.ndarray | None = None
    point: np.ndarray | None = None
    window: np.ndarray | None = None
    strip: np.ndarray | None = None
    depth_point: np.ndarray | None = None
    depth: float = float("nan")
    cost: float = float("nan")
    curve: np.ndarray | None = None
    fused_curve: np.ndarray | None = None


def _nearest(quads: list[np.ndarray], xy: np.ndarray) -> int:
    centres = np.stack(quads).mean(axis=1)                    # (P, 2)
    return int(np.argmin(np.linalg.norm(centres - xy, axis=1)))


def explain_pixel(res, i: int, j: int, xy, supports: list[int] | None = None) -> PixelEvidence:
    """Evidence behind P(x|I_j) at reference pixel xy (working resolution) for the admitted pair
    (i, j) of a run.SetResult. Uses the pair's own result (and, for epipolar pairs, the matcher's
    describe functions on the covering patches' strips only). For swept pairs, `supports` is the
    support set whose shared depth is explained (default: the reference's ready supports)."""
    pair = res.pair_results[(i, j)]
    xy = np.asarray(xy, np.float64).reshape(2)
    ev = _explain_strips(res, i, j, xy)
    if pair.sweep is not None:
        ev = _with_sweep(res, ev, pair, res.pairs[(i, j)], xy, supports)
    return ev


def _explain_strips(res, i: int, j: int, xy: np.ndarray) -> PixelEvidence:
    pair, g = res.pair_results[(i, j)], res.pairs[(i, j)]
    h, w = pair.evidence.shape
    u, v = int(np.clip(round(xy[0]), 0, w - 1)), int(np.clip(round(xy[1]), 0, h - 1))
    ev = float(pair.evidence[v, u])
    if pair.kind == "homography":
        return _explain_homography(res.params, pair, xy, ev)
    line = g.F @ np.array([xy[0], xy[1], 1.0])
    covering = patches_at(pair, xy[None])[0]
    if len(covering) == 0:
        return PixelEvidence(i, j, "epipolar", xy, ev, 0, None, line=line)
    evs = res.explain(i, j, patch_ids=covering)
    dom = evs[_nearest([e.ref_quad for e in evs], xy)]
    return PixelEvidence(i, j, "epipolar", xy, ev, len(evs), dom, line=line)


def _explain_homography(params: Params, pair: PairResult, xy: np.ndarray, ev: float) -> PixelEvidence:
    from .homography import PAD
    t = pair.patches
    s = patch_length(params) // 3
    px = int(t.start.max()) + 1
    py = int(t.strip.max()) + 1
    # the patch whose centre ((i - PAD + 1.5) s - 0.5) is nearest the pixel (homography._splat_grid)
    bi = int(np.clip(round((xy[1] + 0.5) / s - 1.5 + PAD), 0, py - 1))
    bj = int(np.clip(round((xy[0] + 0.5) / s - 1.5 + PAD), 0, px - 1))
    pid = bi * px + bj

    def square(di: int, dj: int, grow: int = 0) -> np.ndarray:
        x0, y0 = (bj + dj - PAD - grow) * s, (bi + di - PAD - grow) * s
        x1, y1 = x0 + 3 * s + 2 * grow * s, y0 + 3 * s + 2 * grow * s
        return np.array([[x0, y0], [x0, y1], [x1, y1], [x1, y0]], np.float64) - 0.5

    def to_sup(pts: np.ndarray) -> np.ndarray:
        q = np.c_[pts, np.ones(len(pts))] @ pair.H.T
        return (q[:, :2] / q[:, 2:3]).astype(np.float32)

    r = params.patches.homography_search
    offsets = [(di, dj) for di in range(-r, r + 1) for dj in range(-r, r + 1)]
    point = to_sup(xy[None])[0].astype(np.float64)
    window = to_sup(square(0, 0, r))
    ref_quad = square(0, 0).astype(np.float32)
    quads, sh, sc = [], [], []
    for k, sim_h, sim_c in ((t.best_hog_seg[pid], t.conf_hog[pid], np.nan),
                            (t.best_color_seg[pid], np.nan, t.conf_color[pid])):
        if k >= 0:
            quads.append(to_sup(square(*offsets[int(k)])))
            sh.append(sim_h)
            sc.append(sim_c)
    if not quads:
        patch = PatchEvidence(pid, ref_quad, np.zeros((0, 4, 2), np.float32), np.zeros(0, np.float32),
                              np.zeros(0, np.float32), -1, -1)
    else:
        patch = PatchEvidence(pid, ref_quad, np.stack(quads), np.array(sh, np.float32), np.array(sc, np.float32),
                              0, len(quads) - 1)
    return PixelEvidence(pair.ref, pair.sup, "homography", xy, ev, 9, patch, point=point, window=window)


def _with_sweep(res, ev: PixelEvidence, pair, g, xy: np.ndarray, supports: list[int] | None) -> PixelEvidence:
    """The strip evidence plus where the shared depth puts the pixel in the support, the bounded
    strip (the part of the epipolar line the depth range allows) and the costs."""
    import dataclasses

    from .sweep import SCALE, UNSEEN
    i, j = pair.ref, pair.sup
    sups = supports if supports is not None else [k for k in res.supports[i] if (i, k) in res.pair_results]
    sw = [k for k in sups if res.is_swept(i, k)]
    f = res.fused(i, sw)
    pairs = res.sweep_pairs(i, sw)                       # on the fusion's grid
    sp_ = pairs[sw.index(j)]
    gh, gw = f.cost.shape
    h, w = res.photo_set.photos[i].size
    gx = int(np.clip(round((xy[0] + 0.5) * gw / w - 0.5), 0, gw - 1))
    gy = int(np.clip(round((xy[1] + 0.5) * gh / h - 0.5), 0, gh - 1))
    raw = sp_.cost[gy, gx].astype(np.float32)
    curve = np.where(raw == UNSEEN, np.nan, raw / SCALE).astype(np.float32)
    s = sw.index(j)
    cost = float(f.per_support[s, gy, gx])
    fused_curve = _fused_curve(res, i, sw, pairs, gy, gx)
    plane = int(f.plane[gy, gx])
    if sp_.kind == "two-view" and sp_.homographies is not None:
        # a pencil without cameras (pencil.py): the support's point at each hypothesis is H x, no depth
        def at(d: int) -> np.ndarray:
            q = sp_.homographies[d] @ np.array([xy[0], xy[1], 1.0])
            return q[:2] / q[2] if abs(q[2]) > 1e-12 else np.array([np.nan, np.nan])
        strip = np.stack([at(0), at(len(sp_.homographies) - 1)])
        return dataclasses.replace(ev, strip=strip, depth_point=at(plane) if plane >= 0 else None, cost=cost,
                                   curve=curve, fused_curve=fused_curve)
    if sp_.kind == "aligned" or res.cameras is None or len(sp_.planes) == 0:
        # a direct comparison after the homography: no depth, the point is H x (ev.point)
        return dataclasses.replace(ev, cost=cost, curve=curve, fused_curve=fused_curve)
    cams = res.cameras
    ray = cams.R[i].T @ (np.linalg.inv(cams.K[i]) @ np.array([xy[0], xy[1], 1.0]))

    def project(z: float) -> np.ndarray:
        """The point at depth z (reference camera) on the pixel's ray, in the support."""
        X = np.append(cams.C[i] + ray * z, 1.0) if np.isfinite(z) else np.append(ray, 0.0)
        q = cams.P(j) @ X
        return q[:2] / q[2] if abs(q[2]) > 1e-12 else np.array([np.nan, np.nan])
    # the strip the depths allow: from the nearest plane parallel to the image to infinity
    fronto = sp_.planes[(sp_.planes[:, 0] == 0) & (sp_.planes[:, 1] == 0)]
    strip = np.stack([project(float(fronto[0, 3])), project(float(fronto[-1, 3]))])
    depth = float(sp_.depth_at(np.array([plane]), xy[None], cams.K[i])[0]) if plane >= 0 else float("nan")
    depth_point = project(depth) if plane >= 0 else None
    return dataclasses.replace(ev, strip=strip, depth_point=depth_point, depth=depth, cost=cost, curve=curve,
                               fused_curve=fused_curve)


def _fused_curve(res, i: int, sw: list[int], pairs: list, gy: int, gx: int) -> np.ndarray:
    """(D,) the fused cost of one grid pixel at every plane (sweep.fuse for one pixel); pairs: the
    swept supports' SweepPairs on the fusion's grid (SetResult.sweep_pairs)."""
    from .sweep import agree_count, fused_costs
    D = max(p.cost.shape[2] for p in pairs)
    costs = np.stack([np.broadcast_to(p.cost[gy, gx], (D,)) for p in pairs])       # (S, D) uint8
    sp = res.params.sweep
    return fused_costs(costs, res.same_spot(i, sw), sp.best_share, agree_count(sp, len(sw)))
