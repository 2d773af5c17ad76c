"""Failure gallery: the worst regions of one reference's map, ranked, each with a first diagnosis.

With ground truth, the regions are missed movers (false negatives: moving, P_dynamic at or
below the threshold) and lit-up static regions (false positives), as connected components ranked
by area. Without it, the most uncertain regions: P_dynamic near the threshold, or supports that
disagree. Each region gets a first diagnosis from what the pipeline already computed, with the
figures behind it:

- "no support sees it": no support has a candidate for the region (out of view), so it is "no
  evidence" (P = 0.5 in `default`);
- "geometry uncertain here": a support that votes the wrong way has epipolar lines less certain
  than a quarter of a patch (its `uncertainty_px`), or, where the cameras are known, its line
  passes that far from where the scene's depth puts the point;
- "a look-alike along the strip": a support that says "match" for a missed mover found its best
  candidate far from where the scene's depth puts the point (needs cameras);
- "colour disagrees with HOG": the two descriptors of Eq. 2 say opposite things;
- "one support vetoes": one support alone votes the wrong way against the others;
- "the depth cue disagrees with the strips": the depth sweep (`default`) finds no common depth
  for a static region, or finds one for a mover.

The core (`find_regions`, `diagnose`) is pure numpy/OpenCV on arrays; `reference_evidence`,
`probe_strips` and `build_gallery` read those arrays from a run.SetResult. Everything is at the
reference's working resolution.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

MISSED, FALSE_ALARM, UNCERTAIN = "missed", "false_alarm", "uncertain"
KIND_TITLE = {MISSED: "missed mover", FALSE_ALARM: "static region lit up", UNCERTAIN: "uncertain region"}

SEEN_SHARE = 0.5          # a support "sees" a region when it has candidates for this share of it
VOTE_MARGIN = 0.05        # P(x|I_s) above 0.5 + margin votes "static" (a match), below 0.5 - margin "moving"
COLOUR_DEPARTURE = 0.15   # a descriptor this far from its photo-wide mean (normalised) departs
LOOKALIKE_PATCHES = 1.5   # best candidate this many patch lengths from the expected point: a look-alike
MAX_EXPLAINED = 4         # candidates are looked up for at most this many supports per region (the surest)


@dataclass(frozen=True)
class ReferenceEvidence:
    """What the pipeline computed for one reference, S supports, at working resolution (h, w).

    dynamic: (h, w) float32 P_dynamic in [0, 1]; threshold: the mask's threshold (mask is
    dynamic > threshold); gt: (h, w) uint8 ground truth (0 static, 255 moving, 128 don't care)
    or None; supports: (S,) support stems; match_prob: (S, h, w) float32 P(x|I_s) (Eq. 2);
    hog_prob, color_prob: (S, h, w) float32 each descriptor's normalised confidence (the two
    parts of Eq. 2), NaN where the support has no candidate; evidence: (S, h, w) float32 share of
    Eq. 2's weight from patches with candidates (0 = out of view); depth_prob: (S, h, w) float32
    what each swept support said at the depth all agreed on, as a match probability, NaN where it
    is not swept or does not see the point; depth_cost: (h, w) float32 the fused depth cost (NaN
    where no swept support sees the point), or None without the depth cue; depth_centre: the cost
    at which the depth cue is neutral; uncertainty_px: (S,) float32 epipolar-line uncertainty of
    each pair in working pixels (NaN unknown); source: (S,) geometry source of each pair
    ("reconstruction", "two-view", "homography"); patch_px: patch length L in working pixels.
    """

    stem: str
    dynamic: np.ndarray
    threshold: float
    gt: np.ndarray | None
    supports: tuple[str, ...]
    match_prob: np.ndarray
    hog_prob: np.ndarray
    color_prob: np.ndarray
    evidence: np.ndarray
    depth_prob: np.ndarray
    depth_cost: np.ndarray | None
    depth_centre: float
    uncertainty_px: np.ndarray
    source: tuple[str, ...]
    patch_px: int

    def __post_init__(self):
        h, w = self.dynamic.shape
        S = len(self.supports)
        for name in ("match_prob", "hog_prob", "color_prob", "evidence", "depth_prob"):
            a = getattr(self, name)
            assert a.shape == (S, h, w), f"{name}: shape {a.shape}, expected {(S, h, w)}"
        assert self.gt is None or self.gt.shape == (h, w), f"gt: shape {self.gt.shape}, expected {(h, w)}"
        assert len(self.uncertainty_px) == S and len(self.source) == S

    def typical_hog_colour(self) -> tuple[float, float]:
        """The mean normalised HOG and colour confidence over the whole photo (all supports, where
        they have candidates): the baseline a region's descriptors are compared with."""
        ok = self.evidence >= SEEN_SHARE
        if not ok.any():
            return float("nan"), float("nan")
        return float(np.nanmean(self.hog_prob[ok])), float(np.nanmean(self.color_prob[ok]))


@dataclass(frozen=True)
class Region:
    """One connected region of the reference (8-connected).

    kind: MISSED, FALSE_ALARM or UNCERTAIN; rank: 1 = worst of its kind; area: pixels (working
    resolution); share: area / image area; bbox: (x0, y0, x1, y1) int, exclusive end; pixel: (x, y)
    the point deepest inside it (the one to click); mask: (y1 - y0, x1 - x0) bool, the region
    within its bbox; mean_p: its mean P_dynamic; score: what it is ranked by (area; for uncertain
    regions the summed uncertainty); object_area, object_found: for a missed mover, the area of the
    ground-truth object it belongs to and the share of that object the mask found (else 0, NaN).
    """

    kind: str
    rank: int
    area: int
    share: float
    bbox: tuple[int, int, int, int]
    pixel: tuple[int, int]
    mask: np.ndarray = field(repr=False)
    mean_p: float
    score: float
    object_area: int = 0
    object_found: float = float("nan")

    def full_mask(self, size: tuple[int, int]) -> np.ndarray:
        """(h, w) bool: the region in the whole image."""
        out = np.zeros(size, bool)
        x0, y0, x1, y1 = self.bbox
        out[y0:y1, x0:x1] = self.mask
        return out


@dataclass(frozen=True)
class StripProbe:
    """What one support's strip found at a region's pixel, where the cameras tell where the
    point should be (probe_strips).

    support: stem; expected: (2,) float64 where the scene's depth around the region puts the
    pixel in the support (NaN unknown); line_px: distance of `expected` from the pair's epipolar
    line (the geometry's error at this pixel); cand_px: distance of the best HOG candidate's centre
    from `expected`; cand_sim: its HOG similarity (raw cosine); near_sim: the best HOG similarity
    among candidates within a patch length of `expected` (NaN when none is).
    """

    support: str
    expected: np.ndarray
    line_px: float
    cand_px: float
    cand_sim: float
    near_sim: float


@dataclass(frozen=True)
class Diagnosis:
    """One possible cause of a region's error. code: "no_view", "geometry", "lookalike",
    "colour_hog", "veto", "depth", "strips" or "borderline"; title: the cause in a few words; detail: one
    sentence with the figures; strength: in [0, 1], how clearly the data point to it; figures:
    the numbers behind it (JSON-friendly)."""

    code: str
    title: str
    detail: str
    strength: float
    figures: dict


@dataclass(frozen=True)
class GalleryEntry:
    """A region, its diagnoses (strongest first; never empty) and its per-support figures:
    support_figures[s] = {support, sees, p, hog, colour, depth, uncertainty_px, source, vote}."""

    region: Region
    diagnoses: tuple[Diagnosis, ...]
    support_figures: tuple[dict, ...]

    @property
    def headline(self) -> Diagnosis:
        return self.diagnoses[0]


@dataclass(frozen=True)
class Gallery:
    """One reference's gallery: entries by kind (missed movers, false alarms; or uncertain
    regions without ground truth), each ranked. counts: regions found per kind before the cut."""

    stem: str
    has_gt: bool
    threshold: float
    entries: tuple[GalleryEntry, ...]
    counts: dict


# ----------------------------------------------------------------------------- regions
def gt_at(gt: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """(H, W) uint8 ground truth -> (h, w) uint8 at working resolution (nearest: 0/128/255 kept)."""
    h, w = size
    return cv2.resize(gt, (w, h), interpolation=cv2.INTER_NEAREST) if gt.shape != (h, w) else gt


def _open(mask: np.ndarray, k: int) -> np.ndarray:
    if k <= 1:
        return mask
    se = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))
    return cv2.morphologyEx(mask.astype(np.uint8), cv2.MORPH_OPEN, se) > 0


def uncertainty_map(dynamic: np.ndarray, threshold: float, match_prob: np.ndarray | None = None,
                    evidence: np.ndarray | None = None, band: float = 0.1) -> np.ndarray:
    """How undecided each pixel is, (h, w) float32 in [0, 1]: the larger of closeness to the
    threshold (1 at it, 0 at |P - t| >= band) and the supports' disagreement (the spread of
    P(x|I_s) among the supports that see the pixel: 0 below 0.3, 1 from 0.7), the latter counted
    only within 2 bands of the threshold (a clear decision stays clear)."""
    d = np.abs(dynamic.astype(np.float32) - threshold)
    u = np.clip(1.0 - d / band, 0.0, 1.0)
    if match_prob is not None and len(match_prob) >= 2:
        seen = (evidence > SEEN_SHARE) if evidence is not None else np.ones(match_prob.shape, bool)
        hi = np.where(seen, match_prob, -np.inf).max(axis=0)
        lo = np.where(seen, match_prob, np.inf).min(axis=0)
        spread = np.where(seen.sum(axis=0) >= 2, hi - lo, 0.0)
        dis = np.clip((spread - 0.3) / 0.4, 0.0, 1.0) * (d < 2 * band)
        u = np.maximum(u, dis)
    return u.astype(np.float32)


def find_regions(dynamic: np.ndarray, threshold: float, gt: np.ndarray | None = None, min_area: int = 16,
                 open_px: int = 3, uncertainty: np.ndarray | None = None) -> list[Region]:
    """Connected regions to look at, ranked per kind (rank 1 = worst).

    dynamic: (h, w) float32 P_dynamic; gt: (h, w) uint8 (0 / 255 / 128) or None. With gt:
    MISSED = moving and not in the mask, FALSE_ALARM = static (not don't care) and in the mask,
    each as 8-connected components ranked by area. Without: UNCERTAIN = pixels whose
    `uncertainty` ((h, w) in [0, 1], default from P_dynamic alone, see uncertainty_map) exceeds
    0.5, ranked by summed uncertainty. Masks are opened with a disc of `open_px` first (slivers
    along a boundary one pixel off are not regions); smaller than `min_area` pixels: dropped.
    """
    h, w = dynamic.shape
    pred = dynamic > threshold
    if gt is not None:
        moving, care = gt == 255, gt != 128
        kinds = [(MISSED, moving & ~pred, None), (FALSE_ALARM, pred & ~moving & care, None)]
        objects_n, objects = cv2.connectedComponents(moving.astype(np.uint8), connectivity=8)
    else:
        u = uncertainty if uncertainty is not None else uncertainty_map(dynamic, threshold)
        kinds = [(UNCERTAIN, u > 0.5, u)]
        objects = None
    out: list[Region] = []
    for kind, m, weight in kinds:
        n, lab, stats, _ = cv2.connectedComponentsWithStats(_open(m, open_px).astype(np.uint8), connectivity=8)
        keep = [k for k in range(1, n) if stats[k, cv2.CC_STAT_AREA] >= min_area]
        if not keep:
            continue
        # per-component sums in one pass (no loop over pixels)
        idx = lab.ravel()
        sum_p = np.bincount(idx, weights=dynamic.ravel().astype(np.float64), minlength=n)
        score = np.bincount(idx, weights=weight.ravel().astype(np.float64), minlength=n) if weight is not None \
            else stats[:, cv2.CC_STAT_AREA].astype(np.float64)
        regions = []
        for k in keep:
            x, y, bw, bh, area = (int(v) for v in stats[k])
            sub = lab[y:y + bh, x:x + bw] == k
            # the point deepest inside: the maximum of the distance to the region's border
            dist = cv2.distanceTransform(np.pad(sub, 1).astype(np.uint8), cv2.DIST_L2, 3)[1:-1, 1:-1]
            py, px = np.unravel_index(int(np.argmax(dist)), dist.shape)
            obj_area, found = 0, float("nan")
            if kind == MISSED and objects is not None:
                ids = np.unique(objects[y:y + bh, x:x + bw][sub])
                ids = ids[ids > 0]
                obj = np.isin(objects, ids)
                obj_area = int(obj.sum())
                found = float((obj & pred).sum() / max(obj_area, 1))
            regions.append(Region(kind, 0, area, area / float(h * w), (x, y, x + bw, y + bh), (x + int(px), y + int(py)),
                                  sub, float(sum_p[k] / area), float(score[k]), obj_area, found))
        regions.sort(key=lambda r: -r.score)
        out += [_with_rank(r, n + 1) for n, r in enumerate(regions)]
    return out


def _with_rank(r: Region, rank: int) -> Region:
    import dataclasses
    return dataclasses.replace(r, rank=rank)


# ----------------------------------------------------------------------------- diagnosis
def _region_means(ev: ReferenceEvidence, region: Region) -> dict[str, np.ndarray]:
    """Per support, means over the region's pixels: (S,) float64 each (NaN where undefined)."""
    x0, y0, x1, y1 = region.bbox
    m = region.mask

    def mean(a):                     # (S, h, w) -> (S,) nan-mean over the region
        v = a[:, y0:y1, x0:x1][:, m].astype(np.float64)
        ok = np.isfinite(v)
        with np.errstate(invalid="ignore"):
            return np.where(ok.any(axis=1), np.where(ok, v, 0).sum(axis=1) / np.maximum(ok.sum(axis=1), 1), np.nan)

    def share_finite(a):
        return np.isfinite(a[:, y0:y1, x0:x1][:, m]).mean(axis=1)
    out = {"evidence": mean(ev.evidence), "p": mean(ev.match_prob), "hog": mean(ev.hog_prob),
           "colour": mean(ev.color_prob), "depth": mean(ev.depth_prob), "depth_seen": share_finite(ev.depth_prob)}
    if ev.depth_cost is not None:
        c = ev.depth_cost[y0:y1, x0:x1][m]
        out["depth_cost"] = np.array([np.nanmean(c) if np.isfinite(c).any() else np.nan])
        out["depth_cost_seen"] = np.array([np.isfinite(c).mean()])
    return out


def _fmt(v: float, nd: int = 2) -> str:
    return "–" if v is None or not np.isfinite(v) else f"{v:.{nd}f}"


def diagnose(ev: ReferenceEvidence, region: Region, probes: dict[str, StripProbe] | None = None) -> GalleryEntry:
    """A first diagnosis of `region` from the reference's evidence (and, when given, strip probes
    per support stem: see probe_strips). Diagnoses come strongest first; when no cause stands
    out, the only one is "borderline" (P near the threshold) or "no single cause"."""
    probes = probes or {}
    S = len(ev.supports)
    f = _region_means(ev, region)
    sees = (f["evidence"] >= SEEN_SHARE) | (f["depth_seen"] >= SEEN_SHARE)
    p = f["p"]
    # the "wrong" vote: for a false alarm, saying "no match" (moving); for a missed mover "match"
    if region.kind == FALSE_ALARM:
        wrong = sees & (p < 0.5 - VOTE_MARGIN)
        right = sees & (p > 0.5 + VOTE_MARGIN)
    elif region.kind == MISSED:
        wrong = sees & (p > 0.5 + VOTE_MARGIN)
        right = sees & (p < 0.5 - VOTE_MARGIN)
    else:                            # uncertain: the minority vote is the odd one out
        hi, lo = sees & (p > 0.5 + VOTE_MARGIN), sees & (p < 0.5 - VOTE_MARGIN)
        wrong, right = (hi, lo) if hi.sum() <= lo.sum() else (lo, hi)
    limit = ev.patch_px / 4.0
    rows = []
    for s in range(S):
        vote = "match" if p[s] > 0.5 + VOTE_MARGIN else "no match" if p[s] < 0.5 - VOTE_MARGIN else "unsure"
        rows.append({"support": ev.supports[s], "sees": bool(sees[s]), "evidence": round(float(f["evidence"][s]), 2),
                     "p": _r(p[s]), "hog": _r(f["hog"][s]), "colour": _r(f["colour"][s]), "depth": _r(f["depth"][s]),
                     "uncertainty_px": _r(ev.uncertainty_px[s], 1), "source": ev.source[s],
                     "vote": vote if sees[s] else "does not see it"})
    out: list[Diagnosis] = []
    n_see = int(sees.sum())

    # 1. no support sees it
    if S and n_see == 0:
        out.append(Diagnosis("no_view", "no support sees it",
                             f"none of the {S} supports has a candidate here (evidence at most "
                             f"{_fmt(np.nanmax(f['evidence']))} of Eq. 2's weight): it is out of their view, so it "
                             f"counts as no evidence (P {region.mean_p:.2f})",
                             1.0, {"supports": S, "seeing": 0, "max_evidence": _r(np.nanmax(f["evidence"]))}))
    elif S >= 3 and n_see == 1:
        s = int(np.argmax(sees))
        out.append(Diagnosis("no_view", "only one support sees it",
                             f"only {ev.supports[s]} of {S} supports has candidates here; its vote is "
                             f"{rows[s]['vote']} (P(x|I_s) {_fmt(p[s])})", 0.55,
                             {"supports": S, "seeing": 1, "support": ev.supports[s]}))

    # 2. geometry uncertain here: a wrong-voting support with uncertain lines (or, with cameras, a
    #    line that misses the point)
    geo = []
    for s in np.nonzero(wrong)[0]:
        pr = probes.get(ev.supports[s])
        meas = pr.line_px if pr is not None else np.nan
        unc = float(ev.uncertainty_px[s])
        if (np.isfinite(meas) and meas > limit) or (np.isfinite(unc) and unc > limit):
            geo.append((ev.supports[s], unc, meas, ev.source[s]))
    if geo:
        parts = []
        for stem, unc, meas, src in geo:
            t = f"{stem} ({src}): lines uncertain to {_fmt(unc, 1)} px"
            if np.isfinite(meas):
                t += f", its line passes {meas:.1f} px from where the cameras put the point"
            parts.append(t)
        strength = 0.9 if any(np.isfinite(g[2]) and g[2] > limit for g in geo) else 0.7
        out.append(Diagnosis("geometry", "geometry uncertain here",
                             "; ".join(parts) + f" (a patch is {ev.patch_px} px; more than {limit:.0f} px off and "
                             "the strip can miss the point)", strength,
                             {"limit_px": limit, "supports": [{"support": g[0], "uncertainty_px": _r(g[1], 1),
                                                               "line_px": _r(g[2], 1), "source": g[3]} for g in geo]}))

    # 3. a look-alike along the strip (missed movers, uncertain regions; needs the cameras)
    if region.kind != FALSE_ALARM:
        look = []
        for s in np.nonzero(wrong if region.kind == MISSED else sees & (p > 0.5 + VOTE_MARGIN))[0]:
            pr = probes.get(ev.supports[s])
            if pr is None or not np.isfinite(pr.cand_px) or pr.cand_px <= LOOKALIKE_PATCHES * ev.patch_px:
                continue
            if np.isfinite(pr.line_px) and pr.line_px > limit:
                continue                  # the strip misses the point: geometry, not a look-alike
            if np.isfinite(pr.near_sim) and pr.cand_sim - pr.near_sim < 0.1:
                continue                  # as good a match where the point should be: no look-alike
            look.append((ev.supports[s], pr))
        if look:
            share = len(look) / max(int(wrong.sum()), 1)
            parts = [f"{stem}: best HOG candidate {pr.cand_px:.0f} px from where the depth of its surroundings puts the point "
                     f"(similarity {pr.cand_sim:.2f}" + (f"; {pr.near_sim:.2f} there)" if np.isfinite(pr.near_sim)
                                                         else "; none there)") for stem, pr in look]
            out.append(Diagnosis("lookalike", "a look-alike along the strip", "; ".join(parts),
                                 0.5 + 0.4 * min(share, 1.0),
                                 {"supports": [{"support": st, "cand_px": _r(pr.cand_px, 1), "cand_sim": _r(pr.cand_sim),
                                                "near_sim": _r(pr.near_sim), "line_px": _r(pr.line_px, 1)}
                                               for st, pr in look]}))

    # 4. colour disagrees with HOG: one descriptor departs from what it says over the whole photo
    #    (HOG's normalised confidences run higher than colour's everywhere; only a departure is
    #    news) in the direction of the error, while the other does not; judged on the supports
    #    that vote the wrong way (or all that see it, when none does)
    pick = wrong if (wrong.any() or region.kind != UNCERTAIN) else sees     # no wrong vote: the strips did not fail
    if pick.any():
        hog, col = np.nanmean(np.where(pick, f["hog"], np.nan)), np.nanmean(np.where(pick, f["colour"], np.nan))
        hog0, col0 = ev.typical_hog_colour()
        dh, dc = hog - hog0, col - col0
        sign = -1.0 if region.kind == FALSE_ALARM else 1.0       # the direction of the error
        if region.kind == UNCERTAIN:
            sign = 1.0 if abs(dh) >= abs(dc) and dh > 0 or abs(dc) > abs(dh) and dc > 0 else -1.0
        lead, other = (dh, dc) if sign * dh >= sign * dc else (dc, dh)
        if np.isfinite(lead) and np.isfinite(other) and sign * lead >= COLOUR_DEPARTURE and \
                sign * other < sign * lead / 2:
            name_l, name_o = ("HOG", "colour") if lead is dh else ("colour", "HOG")
            v_l, v_o, t_l, t_o = (hog, col, hog0, col0) if lead is dh else (col, hog, col0, hog0)
            says = "a match" if sign > 0 else "no match"
            out.append(Diagnosis("colour_hog", "colour disagrees with HOG",
                                 f"{name_l} finds {says} here ({v_l:.2f}, against {t_l:.2f} over the photo) while "
                                 f"{name_o} says what it says elsewhere ({v_o:.2f}, against {t_o:.2f}); over "
                                 f"{int(pick.sum())} support{'s' if pick.sum() != 1 else ''} "
                                 f"({', '.join(ev.supports[k] for k in np.nonzero(pick)[0])}); "
                                 f"Eq. 2 weighs HOG 2 : colour 1",
                                 float(np.clip(0.45 + abs(lead - other) - COLOUR_DEPARTURE, 0.45, 0.8)),
                                 {"hog": _r(hog), "colour": _r(col), "hog_photo": _r(hog0), "colour_photo": _r(col0),
                                  "departs": name_l}))

    # 5. one support vetoes: it alone votes the wrong way, the others the right way
    if int(wrong.sum()) == 1 and int(right.sum()) >= 2 and abs(p[int(np.argmax(wrong))] - 0.5) >= 2 * VOTE_MARGIN:
        s = int(np.argmax(wrong))
        others = float(np.mean(p[right]))
        out.append(Diagnosis("veto", "one support vetoes",
                             f"{ev.supports[s]} alone says {rows[s]['vote']} (P(x|I_s) {p[s]:.2f}) where "
                             f"{int(right.sum())} others say {'match' if others > 0.5 else 'no match'} "
                             f"(mean {others:.2f})", 0.75 if abs(p[s] - 0.5) > 0.2 else 0.6,
                             {"support": ev.supports[s], "p": _r(p[s]), "others_mean_p": _r(others),
                              "others": int(right.sum())}))
    # ... the same within the depth cue (what each swept support said at the agreed depth)
    dsee = np.isfinite(f["depth"]) & (f["depth_seen"] >= SEEN_SHARE)
    if dsee.sum() >= 3 and region.kind == FALSE_ALARM:
        dp = np.where(dsee, f["depth"], np.nan)
        low = np.nonzero(dsee & (dp < 0.5 - VOTE_MARGIN))[0]
        if len(low) == 1 and np.sum(dsee & (dp > 0.5 + VOTE_MARGIN)) >= 2 and not any(d.code == "veto" for d in out):
            s = int(low[0])
            out.append(Diagnosis("veto", "one support vetoes",
                                 f"at the depth the supports agreed on, {ev.supports[s]} alone does not match "
                                 f"({dp[s]:.2f}) where the others do (mean {np.nanmean(np.delete(dp, s)):.2f})", 0.6,
                                 {"support": ev.supports[s], "depth_p": _r(dp[s]), "cue": "depth"}))

    # 6. the depth cue disagrees with the strips
    if ev.depth_cost is not None and "depth_cost" in f and np.isfinite(f["depth_cost"][0]):
        c = float(f["depth_cost"][0])
        strips = float(np.nanmean(np.where(sees, p, np.nan))) if n_see else np.nan
        # the more of the strips vote the right way, the more the depth cue alone is to blame
        alone = float(right.sum()) / max(n_see, 1)
        if region.kind == FALSE_ALARM and c > ev.depth_centre and not (np.isfinite(strips) and strips < 0.5):
            out.append(Diagnosis("depth", "no common depth found",
                                 f"the depth sweep finds no depth at which the supports agree (fused cost {c:.2f}, "
                                 f"neutral at {ev.depth_centre:.2f}) while the strips say match "
                                 f"(mean P(x|I_s) {_fmt(strips)}, {int(right.sum())} of {n_see} supports)",
                                 float(np.clip(0.45 + 2 * (c - ev.depth_centre) + 0.35 * alone, 0.5, 0.85)),
                                 {"depth_cost": _r(c), "centre": ev.depth_centre, "strips_p": _r(strips)}))
        elif region.kind == MISSED and c < ev.depth_centre:
            out.append(Diagnosis("depth", "the supports agree on a depth",
                                 f"the depth sweep finds a depth at which the supports agree (fused cost {c:.2f}, "
                                 f"below the neutral {ev.depth_centre:.2f}): the mover looks like what the supports see "
                                 "there", float(np.clip(0.45 + 2 * (ev.depth_centre - c) + 0.35 * alone, 0.5, 0.85)),
                                 {"depth_cost": _r(c), "centre": ev.depth_centre, "strips_p": _r(strips)}))

    # 7. the strips themselves: most supports that see it vote the wrong way (no finer cause found)
    if n_see >= 2 and int(wrong.sum()) > n_see / 2 and region.kind != UNCERTAIN:
        said = "no match" if region.kind == FALSE_ALARM else "a match"
        out.append(Diagnosis("strips", f"most supports find {said}",
                             f"{int(wrong.sum())} of the {n_see} supports that see it find {said} along the strip "
                             f"(mean P(x|I_s) {np.mean(p[wrong]):.2f})" +
                             (": a change of look (light, reflection, blur) or a surface the patches cannot match"
                              if region.kind == FALSE_ALARM else ""), 0.45,
                             {"wrong": int(wrong.sum()), "seeing": n_see, "mean_p": _r(np.mean(p[wrong]))}))

    if not out:
        d = abs(region.mean_p - ev.threshold)
        title = "borderline" if d < 0.1 else "no single cause"
        out.append(Diagnosis("borderline", title,
                             f"mean P {region.mean_p:.2f} against the threshold {ev.threshold:.2f}; {n_see} of {S} "
                             f"supports see it, votes: {sum(r['vote'] == 'match' for r in rows)} match, "
                             f"{sum(r['vote'] == 'no match' for r in rows)} no match", 0.3,
                             {"mean_p": _r(region.mean_p), "threshold": ev.threshold}))
    out.sort(key=lambda d: -d.strength)
    return GalleryEntry(region, tuple(out), tuple(rows))


def _r(v, nd: int = 2):
    v = float(v)
    return round(v, nd) if np.isfinite(v) else None


def gallery_from_evidence(ev: ReferenceEvidence, max_per_kind: int = 5, probe=None, min_area: int | None = None,
                          open_px: int | None = None) -> Gallery:
    """Regions of one reference (find_regions, ranked) and the first `max_per_kind` of each kind
    diagnosed. probe(region) -> {support stem: StripProbe}, optional (needs the pipeline run).
    By default a region must hold a disc of a quarter patch (open_px) and a quarter of a patch's
    area (min_area: (L/2)^2 px, 144 at 640 px)."""
    L = ev.patch_px
    u = None if ev.gt is not None else uncertainty_map(ev.dynamic, ev.threshold, ev.match_prob, ev.evidence)
    regions = find_regions(ev.dynamic, ev.threshold, ev.gt,
                           min_area=max(9, (L // 2) ** 2) if min_area is None else min_area,
                           open_px=max(3, (L // 4) | 1) if open_px is None else open_px, uncertainty=u)
    counts: dict[str, int] = {}
    entries = []
    for r in regions:
        counts[r.kind] = counts.get(r.kind, 0) + 1
        if r.rank <= max_per_kind:
            entries.append(diagnose(ev, r, probe(r) if probe is not None else None))
    return Gallery(ev.stem, ev.gt is not None, ev.threshold, tuple(entries), counts)


# ----------------------------------------------------------------------------- from a run
def reference_evidence(res, i: int, gt: np.ndarray | None = None, threshold: float | None = None,
                       supports: list[int] | None = None) -> ReferenceEvidence:
    """The arrays of ReferenceEvidence for photo i of a run.SetResult (its supports by default;
    gt: (H, W) uint8 at any size, resized to working resolution)."""
    from .matching import patch_length
    p = res.params
    photo = res.photo_set.photos[i]
    h, w = photo.size
    sups = [j for j in (supports if supports is not None else res.supports[i]) if (i, j) in res.pair_results]
    dyn = res.dynamic[i] if res.dynamic[i] is not None and supports is None else res.dynamic_prob(i, sups)
    S = len(sups)
    mp = np.zeros((S, h, w), np.float32)
    hog = np.full((S, h, w), np.nan, np.float32)
    col = np.full((S, h, w), np.nan, np.float32)
    evid = np.zeros((S, h, w), np.float32)
    dprob = np.full((S, h, w), np.nan, np.float32)
    nz = res.normaliser

    def nrm(m, lo_hi):
        lo, hi = lo_hi
        return np.clip((m - lo) / (hi - lo), 0.0, 1.0)
    for s, j in enumerate(sups):
        r = res.pair_results[(i, j)]
        mp[s] = res.match_prob(i, j)
        if r.kind == "peer":
            evid[s] = np.isfinite(r.diff)
            continue
        hog[s] = nrm(r.hog_map, nz.hog)
        col[s] = nrm(r.color_map, nz.color)
        evid[s] = r.evidence
    cost = None
    swept = [j for j in sups if res.is_swept(i, j)]
    if swept and p.sweep.enabled and p.sweep.weight > 0:
        from .run import calibrated_log_odds
        f = res.fused(i, swept)
        up = lambda a: cv2.resize(a.astype(np.float32), (w, h), interpolation=cv2.INTER_NEAREST)
        cost = up(f.cost)
        for k, j in enumerate(swept):
            c = up(f.per_support[k])
            dprob[sups.index(j)] = 1.0 / (1.0 + np.exp(-calibrated_log_odds(c, p)))     # NaN stays NaN
    g = res.pairs
    return ReferenceEvidence(
        photo.stem, dyn.astype(np.float32), float(p.aggregate.threshold if threshold is None else threshold),
        None if gt is None else gt_at(gt, (h, w)), tuple(res.photo_set.photos[j].stem for j in sups), mp, hog, col,
        evid, dprob, cost, float(p.sweep.calib_centre),
        np.array([g[(i, j)].uncertainty_px for j in sups], np.float32), tuple(g[(i, j)].source for j in sups),
        int(patch_length(p)))


def scene_depth_around(res, i: int, region: Region, ring_px: int | None = None) -> float:
    """The depth (reference camera z, the reconstruction's units) of the scene just around the
    region: the median of the depths the supports agreed on in a ring around it (NaN when the
    depth cue has none there)."""
    from .matching import patch_length
    cams = res.cameras
    if cams is None or not cams.registered[i]:
        return float("nan")
    swept = [j for j in res.supports[i] if (i, j) in res.pair_results and res.is_swept(i, j)
             and res.pair_results[(i, j)].sweep.kind == "sweep"]
    if not swept:
        return float("nan")
    f = res.fused(i, [j for j in res.supports[i] if (i, j) in res.pair_results and res.is_swept(i, j)])
    h, w = res.photo_set.photos[i].size
    ring_px = ring_px or patch_length(res.params)
    full = region.full_mask((h, w)).astype(np.uint8)
    se = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * ring_px + 1, 2 * ring_px + 1))
    ring = (cv2.dilate(full, se) > 0) & (full == 0)
    plane = cv2.resize(f.plane.astype(np.float32), (w, h), interpolation=cv2.INTER_NEAREST).astype(np.int64)
    ys, xs = np.nonzero(ring & (plane >= 0))
    if len(xs) == 0:
        return float("nan")
    sp = res.pair_results[(i, swept[0])].sweep
    z = sp.depth_at(plane[ys, xs], np.column_stack([xs, ys]).astype(float), cams.K[i])
    z = z[np.isfinite(z)]
    return float(np.median(z)) if len(z) else float("nan")


def strip_probe(support: str, F: np.ndarray, xy, expected, cand_centres: np.ndarray | None = None,
                cand_sims: np.ndarray | None = None, best: int = -1, near_px: float = 0.0) -> StripProbe:
    """A StripProbe from plain geometry: F (3, 3) with x_sup^T F x_ref = 0; xy (2,) the reference
    pixel; expected (2,) where the point is in the support; cand_centres (C, 2) and cand_sims (C,)
    the strip's candidates with `best` the index of the best one (optional); near_px: how close
    to `expected` a candidate must be to count as "there"."""
    expected = np.asarray(expected, np.float64).reshape(2)
    line = np.asarray(F, np.float64) @ np.array([float(xy[0]), float(xy[1]), 1.0])
    line_px = float(abs(line @ np.append(expected, 1.0)) / max(np.hypot(line[0], line[1]), 1e-12))
    cand_px = cand_sim = near_sim = float("nan")
    if cand_centres is not None and len(cand_centres) and best >= 0:
        dist = np.linalg.norm(np.asarray(cand_centres, np.float64) - expected, axis=1)
        cand_px, cand_sim = float(dist[best]), float(cand_sims[best])
        near = dist <= near_px
        near_sim = float(np.max(cand_sims[near])) if near.any() else float("nan")
    return StripProbe(support, expected, line_px, cand_px, cand_sim, near_sim)


def probe_strips(res, i: int, region: Region, supports: list[int] | None = None,
                 explain: set[int] | None = None) -> dict[str, StripProbe]:
    """Strip probes at the region's pixel for the epipolar supports whose photos have cameras:
    where the scene's depth around the region (scene_depth_around) puts the pixel in the support,
    how far the pair's epipolar line passes from it, and, for the supports in `explain` (default
    all), how far the best HOG candidate of the dominant covering patch lies from it
    (explain.explain_pixel; NaN for the others). Empty without cameras."""
    from .explain import explain_pixel
    from .matching import patch_length
    cams = res.cameras
    z = scene_depth_around(res, i, region)
    if cams is None or not np.isfinite(z):
        return {}
    xy = np.array(region.pixel, np.float64)
    ray = cams.R[i].T @ (np.linalg.inv(cams.K[i]) @ np.array([xy[0], xy[1], 1.0]))
    X = np.append(cams.C[i] + ray * z, 1.0)
    out = {}
    for j in supports if supports is not None else res.supports[i]:
        if (i, j) not in res.pair_results or not cams.registered[j] or res.kind(i, j) != "epipolar":
            continue
        q = cams.P(j) @ X
        if q[2] <= 1e-9:
            continue
        exp = q[:2] / q[2]
        ev = None
        if explain is None or j in explain:
            try:
                ev = explain_pixel(res, i, j, xy)
            except cv2.error:           # a covering patch whose support strip holds no sample
                ev = None
        stem = res.photo_set.photos[j].stem
        if ev is not None and ev.patch is not None and ev.patch.best_hog >= 0:
            out[stem] = strip_probe(stem, res.pairs[(i, j)].F, xy, exp, ev.patch.cand_quads.mean(axis=1),
                                    ev.patch.sim_hog, ev.patch.best_hog, patch_length(res.params))
        else:
            out[stem] = strip_probe(stem, res.pairs[(i, j)].F, xy, exp)
    return out


def build_gallery(res, i: int, gt: np.ndarray | None = None, threshold: float | None = None,
                  max_per_kind: int = 5, probes: bool = True) -> Gallery:
    """The failure gallery of photo i of a run (SetResult): regions ranked, each diagnosed, with
    strip probes where the cameras are known (probes=False skips them: they describe the strips
    of the covering patches again, some 10-50 ms per support and region)."""
    ev = reference_evidence(res, i, gt, threshold)
    probe = None
    if probes and res.cameras is not None and res.cameras.registered[i]:
        stems = [ph.stem for ph in res.photo_set.photos]

        def probe(r: Region) -> dict[str, StripProbe]:
            # candidates only where a look-alike can be the cause: supports saying "match" to a
            # mover or to an undecided region; line distances (cheap) for every support
            p = _region_means(ev, r)["p"]
            order = [s for s in np.argsort(-np.nan_to_num(p, nan=-1.0)) if p[s] > 0.5 + VOTE_MARGIN][:MAX_EXPLAINED]
            explain = {stems.index(ev.supports[s]) for s in order} if r.kind != FALSE_ALARM else set()
            return probe_strips(res, i, r, explain=explain)
    return gallery_from_evidence(ev, max_per_kind, probe)


# ----------------------------------------------------------------------------- cues per photo
CUES = ("strips", "depth", "plane")
CUE_TITLE = {"strips": "strips (Eq. 3)", "depth": "depth cue", "plane": "plane-aligned difference"}
# what the cues' tables hold (crowdcam report's, and the inspector's Gallery tab's for one photo)
CUE_INTRO = ("its median static log-odds over the photo's moving pixels and over its static ones (ground "
             "truth; positive reads static, negative moving; – where the map has no such cue), then the map's "
             "median P_dynamic over each. A cue that separates them is much lower on the movers than on the "
             "static pixels.")


@dataclass(frozen=True)
class CueSummary:
    """What each cue of a photo's map says about its moving and its static pixels (ground truth):
    per cue, the median static log-odds over the moving pixels and over the static ones, so that
    positive reads "static" and negative "moving", over the pixels some support saw (NaN: the map
    has no such cue, or no support saw those pixels); `dynamic` the medians of the final P_dynamic. A cue that separates
    them is far lower on the movers than on the static pixels; one that fails is not."""

    stem: str
    moving: dict[str, float]          # cue -> median over the moving pixels
    static: dict[str, float]          # cue -> median over the static pixels
    dynamic: tuple[float, float]      # median P_dynamic over the moving, over the static pixels
    n_moving: int
    n_static: int

    def to_dict(self) -> dict:
        r = lambda v: None if not np.isfinite(v) else round(float(v), 3)
        return {"stem": self.stem, "moving": {k: r(v) for k, v in self.moving.items()},
                "static": {k: r(v) for k, v in self.static.items()},
                "dynamic": [r(v) for v in self.dynamic], "n_moving": self.n_moving, "n_static": self.n_static}


def signed(v: float) -> str:
    """A log-odds for the cues' tables: '+0.31', '-1.20', '0.00' (no '-0.00'), '–' for NaN."""
    if not np.isfinite(v):
        return "–"
    return "0.00" if abs(v) < 0.005 else f"{v:+.2f}"


def cue_summary(res, i: int, gt: np.ndarray, supports: list[int] | None = None,
                dynamic: np.ndarray | None = None) -> CueSummary | None:
    """The CueSummary of photo i of a run (SetResult) against its ground truth gt (any size, 0
    static, 255 moving, 128 don't care); None when the photo has no map or no moving pixel, or
    the run is the peer baseline (no cues). supports and dynamic (h, w) float32: the cues of
    these supports and this map instead of the run's (a viewer's map of the pairs done so far)."""
    p = res.params
    dyn = res.dynamic[i] if dynamic is None else dynamic
    s = res.supports[i] if supports is None else list(supports)
    if dyn is None or p.geometry.peer_homography or not s:
        return None
    g = gt_at(gt, dyn.shape)
    moving, static = g == 255, g == 0
    if not moving.any():
        return None
    # pixels no support saw (every cue 0 there: no evidence) are left out of the medians
    seen = res.has_evidence(i, s)
    cues = {"strips": res.strips_log_odds(i, s),
            "depth": res.sweep_log_odds(i, s) if p.sweep.enabled and p.sweep.weight > 0 else None,
            "plane": res.plane_log_odds(i, s)}

    def med(a, mask):
        return float(np.median(a[mask & seen])) if a is not None and (mask & seen).any() else float("nan")
    return CueSummary(res.photo_set.photos[i].stem, {k: med(v, moving) for k, v in cues.items()},
                      {k: med(v, static) for k, v in cues.items()},
                      (float(np.median(dyn[moving])), float(np.median(dyn[static])) if static.any() else float("nan")),
                      int(moving.sum()), int(static.sum()))
