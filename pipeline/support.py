"""Fundamental matrices per pair and the test that admits a pair to the support set (§3).

The paper keeps "only pairs of images where BEEM succeeded". A robust estimator always returns
*some* F, so success needs a test. On hand-held photos of planar-heavy scenes RANSAC happily
returns a wrong F with many "inliers": the inliers lie on one plane (or the cameras only
rotated), which fixes a homography but leaves F free along a family. A pair is admitted when:

1. enough F inliers (`min_inliers`);
2. they are spread over both images (convex hull share >= `min_spread`): F from a corner of
   the image extrapolates badly;
3. F is not degenerate: one homography must not explain `max_homography_share` of the F inliers
   (a dominant plane, pure rotation, near-zero baseline or a distant scene);
4. F is stable: refitted on a random half of the matches, the other half's inliers stay within
   `max_instability_px` of their epipolar lines (median). Repeated texture and near-degenerate
   configurations give Fs that move a lot between fits.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .features import Features, match
from .geometry import convex_hull_share, line_spread, symmetric_epipolar_distance
from .params import GeometryParams

OK = "ok"                     # epipolar pair: F is trustworthy
HOMOGRAPHY = "homography"     # homography pair: one H explains the static scene (default preset only)
REJECTED = "rejected"


@dataclass(frozen=True)
class PairGeometry:
    """Geometry of an ordered pair (ref, sup) at working resolution.

    F: (3, 3) float64 with x_sup^T F x_ref = 0, or None when no F could be fitted.
    H: (3, 3) float64 with x_sup ~ H x_ref for homography pairs, else None.
    inliers_ref / inliers_sup: (K, 2) float32 matched inlier positions; outliers_*: the rest.
    scale: median ratio of SIFT sizes sup/ref over inliers (the pair's relative zoom).
    inlier_idx: (K, 2) int32 keypoint indices (ref, sup) of the inliers; match_idx: (M, 2) int32
    of all mutual ratio-test matches (the set reconstruction verifies them itself).
    source: where F comes from: "reconstruction" (cameras of the whole set, reconstruction.py),
    "two-view" (this pair's matches alone), "homography", or "" when rejected.
    uncertainty_px: estimated 1-sigma uncertainty of the epipolar lines (or, for homography
    pairs, of the transferred points) in working pixels, 90th percentile over the image; NaN
    when unknown.
    """

    ref: int
    sup: int
    F: np.ndarray | None
    status: str
    reason: str
    n_matches: int
    n_inliers: int
    spread: float
    homography_share: float
    instability_px: float
    scale: float
    inliers_ref: np.ndarray
    inliers_sup: np.ndarray
    outliers_ref: np.ndarray
    outliers_sup: np.ndarray
    H: np.ndarray | None = None
    inlier_idx: np.ndarray | None = None
    match_idx: np.ndarray | None = None
    source: str = ""
    uncertainty_px: float = float("nan")

    @property
    def ok(self) -> bool:
        """The pair joins the support set (as an epipolar or a homography pair)."""
        return self.status in (OK, HOMOGRAPHY)

    @property
    def is_homography(self) -> bool:
        return self.status == HOMOGRAPHY

    def reversed(self) -> "PairGeometry":
        """The same pair seen from the other image: F -> F^T, roles swapped."""
        return PairGeometry(
            ref=self.sup, sup=self.ref, F=None if self.F is None else self.F.T.copy(), status=self.status,
            reason=self.reason, n_matches=self.n_matches, n_inliers=self.n_inliers, spread=self.spread,
            homography_share=self.homography_share, instability_px=self.instability_px,
            scale=1.0 / self.scale if self.scale > 0 else self.scale,
            inliers_ref=self.inliers_sup, inliers_sup=self.inliers_ref,
            outliers_ref=self.outliers_sup, outliers_sup=self.outliers_ref,
            H=None if self.H is None else np.linalg.inv(self.H),
            inlier_idx=None if self.inlier_idx is None else self.inlier_idx[:, ::-1].copy(),
            match_idx=None if self.match_idx is None else self.match_idx[:, ::-1].copy(),
            source=self.source, uncertainty_px=self.uncertainty_px)

    def summary(self) -> dict:
        return {"ref": self.ref, "sup": self.sup, "status": self.status, "reason": self.reason,
                "n_matches": self.n_matches, "n_inliers": self.n_inliers, "spread": round(self.spread, 3),
                "homography_share": round(self.homography_share, 3),
                "instability_px": round(self.instability_px, 3), "scale": round(self.scale, 3),
                "source": self.source or "rejected",
                "uncertainty_px": None if not np.isfinite(self.uncertainty_px) else round(self.uncertainty_px, 2)}


def not_compared(i: int, j: int, reason: str) -> PairGeometry:
    """A rejected pair whose geometry was not estimated (screen.py left it out)."""
    empty = np.zeros((0, 2), np.float32)
    return PairGeometry(i, j, None, REJECTED, reason, 0, 0, 0.0, 0.0, float("nan"), 1.0, empty, empty, empty, empty,
                        inlier_idx=np.zeros((0, 2), np.int32), match_idx=np.zeros((0, 2), np.int32))


def _fit_f(p_ref: np.ndarray, p_sup: np.ndarray, thr: float, seed: int = 0) -> tuple[np.ndarray | None, np.ndarray]:
    if len(p_ref) < 8:
        return None, np.zeros(len(p_ref), bool)
    cv2.setRNGSeed(seed)
    try:
        F, mask = cv2.findFundamentalMat(p_ref, p_sup, cv2.USAC_MAGSAC, thr, 0.9999, 20000)
    except cv2.error:       # USAC asserts on some degenerate samples instead of returning no model
        return None, np.zeros(len(p_ref), bool)
    if F is None or F.shape != (3, 3):
        return None, np.zeros(len(p_ref), bool)
    return F / np.linalg.norm(F), mask.ravel().astype(bool)


def fit_homography(p_ref: np.ndarray, p_sup: np.ndarray, thr: float) -> tuple[np.ndarray | None, np.ndarray | None]:
    """H (3, 3) with x_sup ~ H x_ref and its inlier mask (N, 1) uint8 from (N, 2) float32 matches
    (MAGSAC++, `thr` px), or (None, None)."""
    try:
        H, mask = cv2.findHomography(p_ref, p_sup, cv2.USAC_MAGSAC, thr, None, 10000, 0.9999)
    except cv2.error:
        return None, None
    return (H, mask) if H is not None and mask is not None else (None, None)


def estimate_pair(i: int, j: int, fi: Features, fj: Features, size_i: tuple[int, int],
                  size_j: tuple[int, int], p: GeometryParams) -> PairGeometry:
    """Match features of photos i (reference) and j (support), fit F, and test it."""
    m = match(fi, fj, p.ratio)
    p_ref = fi.xy[m[:, 0]].astype(np.float32)
    p_sup = fj.xy[m[:, 1]].astype(np.float32)

    def result(F, status, reason, inl=None, spread=0.0, hshare=0.0, instab=0.0, scale=1.0, H=None,
               unc=float("nan")):
        inl = np.zeros(len(m), bool) if inl is None else inl
        source = {OK: "two-view", HOMOGRAPHY: "homography"}.get(status, "")
        return PairGeometry(i, j, F, status, reason, len(m), int(inl.sum()), spread, hshare, instab, scale,
                            p_ref[inl], p_sup[inl], p_ref[~inl], p_sup[~inl], H, m[inl].astype(np.int32),
                            m.astype(np.int32), source, unc)

    if len(m) < max(8, p.min_inliers):
        return result(None, REJECTED, f"too few feature matches ({len(m)} < {max(8, p.min_inliers)})")
    if p.peer_homography:              # the peer baseline: one homography per pair, no other test
        H, hmask = fit_homography(p_ref, p_sup, p.ransac_px * 2.0)
        inl = np.zeros(len(m), bool) if hmask is None else hmask.ravel().astype(bool)
        if H is None or inl.sum() < p.min_inliers:
            return result(None, REJECTED, f"no homography with {p.min_inliers} inliers", inl)
        return result(None, HOMOGRAPHY, "aligned by one homography (peer baseline)", inl, H=H / H[2, 2])
    F, inl = _fit_f(p_ref, p_sup, p.ransac_px)
    if F is None:
        return result(None, REJECTED, "no fundamental matrix could be fitted")
    n_in = int(inl.sum())
    scale = float(np.median(fj.size[m[inl, 1]] / np.maximum(fi.size[m[inl, 0]], 1e-6))) if n_in else 1.0
    if n_in < p.min_inliers:
        return result(F, REJECTED, f"too few inliers ({n_in} < {p.min_inliers})", inl, scale=scale)
    spread = min(convex_hull_share(p_ref[inl], size_i), convex_hull_share(p_sup[inl], size_j))
    if spread < p.min_spread:
        return result(F, REJECTED, f"inliers poorly spread (hull covers {spread:.0%} < {p.min_spread:.0%})",
                      inl, spread, scale=scale)
    # Degeneracy: does one homography explain (almost) all F inliers?
    H, hmask = fit_homography(p_ref[inl], p_sup[inl], p.ransac_px * 2.0)
    hshare = float(hmask.sum()) / n_in if H is not None else 0.0
    if hshare >= p.max_homography_share and p.homography_pairs:
        return _homography_pair(i, j, F, inl, p_ref, p_sup, size_i, size_j, scale, hshare, p, result)
    if hshare >= p.max_homography_share:
        return result(F, REJECTED, f"degenerate: one homography explains {hshare:.0%} of the inliers "
                      "(dominant plane, pure rotation or no baseline)", inl, spread, hshare, scale=scale)
    # Stability: refit on a random half of the matches, measure the other inliers' distances.
    rng = np.random.default_rng(12345)
    half = rng.random(len(m)) < 0.5
    F2, _ = _fit_f(p_ref[half], p_sup[half], p.ransac_px, seed=1)
    test = inl & ~half
    if F2 is None or test.sum() < 8:
        instab = float("inf")
    else:
        instab = float(np.median(symmetric_epipolar_distance(F2, p_ref[test], p_sup[test])))
    if not instab <= p.max_instability_px:
        return result(F, REJECTED, f"unstable: F refitted on half the matches moves inliers by "
                      f"{instab:.1f} px (> {p.max_instability_px} px)", inl, spread, hshare, instab, scale)
    # Uncertainty over the whole image, not only at the inliers: the spread of the lines of the
    # two half-data refits around F's (a two-sample bootstrap); a half fit has sqrt(2) x the noise.
    F3, _ = _fit_f(p_ref[~half], p_sup[~half], p.ransac_px, seed=2)
    spreads = [line_spread(F, Fk, size_i, size_j) for Fk in (F2, F3) if Fk is not None]
    unc = float(np.mean(spreads) / np.sqrt(2)) if spreads else float("inf")
    return result(F, OK, "", inl, spread, hshare, instab, scale, unc=unc)


def _homography_pair(i, j, F, f_inl, p_ref, p_sup, size_i, size_j, scale, hshare, p: GeometryParams, result):
    """Departure (default preset): a pair whose static scene one homography explains (same spot,
    pure rotation, distant or planar scene) is kept as a homography pair instead of dropped.
    Its epipolar strip collapses to the point H gives, which makes it the most informative kind."""
    H, hmask = fit_homography(p_ref, p_sup, p.ransac_px * 2.0)
    if H is None:
        return result(F, REJECTED, "degenerate F and no homography could be fitted", hshare=hshare, scale=scale)
    inl = hmask.ravel().astype(bool)
    n_in = int(inl.sum())
    spread = min(convex_hull_share(p_ref[inl], size_i), convex_hull_share(p_sup[inl], size_j))
    if n_in < p.min_inliers or spread < p.min_spread:
        return result(F, REJECTED, f"degenerate F, and the homography has {n_in} inliers covering {spread:.0%}",
                      inl, spread, hshare, scale=scale)
    # Static points off the dominant plane show parallax after alignment. The point-to-point
    # comparison searches only a small window, so every matched static point (the F inliers
    # f_inl) must land within it.
    ph = np.concatenate([p_ref[f_inl], np.ones((int(f_inl.sum()), 1), np.float32)], axis=1) @ H.T
    transfer = np.linalg.norm(ph[:, :2] / ph[:, 2:3] - p_sup[f_inl], axis=1)
    parallax = float(np.percentile(transfer, 95)) if len(transfer) else 0.0
    limit = p.homography_parallax_frac * max(size_i)
    if parallax > limit:
        return result(F, REJECTED, f"degenerate F, and residual parallax after the homography is {parallax:.1f} px "
                      f"(> {limit:.1f} px)", inl, spread, hshare, scale=scale)
    return result(F, HOMOGRAPHY, f"homography pair: one homography explains {hshare:.0%} of the inliers",
                  inl, spread, hshare, scale=scale, H=H / H[2, 2], unc=parallax)


def position_keys(xy: np.ndarray) -> np.ndarray:
    """(N, 2) float32 positions -> (N,) uint64 keys, equal exactly where the positions are."""
    return np.ascontiguousarray(xy, np.float32).view(np.uint64).ravel()


def _index_of(pairs, i: int, j: int, memo: dict) -> tuple[np.ndarray, np.ndarray]:
    """The (sorted keys, row) of pair (i, j)'s reference inliers by position; where a position
    repeats, its last row (memoised per pair: a triplet check asks for every pair many times)."""
    if (i, j) not in memo:
        keys = position_keys(pairs[(i, j)].inliers_ref)
        uniq, first_rev = np.unique(keys[::-1], return_index=True)
        memo[(i, j)] = (uniq, len(keys) - 1 - first_rev)
    return memo[(i, j)]


def _chained(pairs, i: int, j: int, k: int, min_tracks: int = 8, memo: dict | None = None) -> float | None:
    """Median distance of chained matches x_j <- x_i -> x_k to their epipolar lines under F_jk
    (the keypoints of photo i matched, as inliers, in both (i, j) and (i, k)); None if too few."""
    g_ij, g_ik, g_jk = pairs[(i, j)], pairs[(i, k)], pairs[(j, k)]
    uniq, row = _index_of(pairs, i, j, {} if memo is None else memo)
    keys = position_keys(g_ik.inliers_ref)
    at = np.minimum(np.searchsorted(uniq, keys), max(len(uniq) - 1, 0))
    found = (uniq[at] == keys) if len(uniq) else np.zeros(len(keys), bool)
    b = np.nonzero(found)[0]
    a = row[at[b]]
    if len(a) < min_tracks:
        return None
    return float(np.median(symmetric_epipolar_distance(g_jk.F, g_ij.inliers_sup[a], g_ik.inliers_sup[b])))


def triplet_check(pairs: dict[tuple[int, int], PairGeometry], n: int, max_px: float
                  ) -> dict[tuple[int, int], PairGeometry]:
    """Departure (default preset): reject epipolar pairs that disagree with the other pairs.

    Repeated texture makes SIFT match the wrong copy; the wrong F then fits its inliers in two
    views and passes every two-view test. Three views expose it: for a triplet (a, b, c), matches
    chained through one photo must satisfy the F of the other two. A triplet is consistent when
    its three closings stay within `max_px` (median). A pair that sits in evaluable triplets and is
    consistent in fewer than half of them is rejected. Returns the updated pairs (both orders).
    """
    import dataclasses
    ok = lambda a, b: pairs[(a, b)].status == OK
    two_view = lambda a, b: pairs[(a, b)].source == "two-view"
    votes: dict[tuple[int, int], list[int]] = {}
    memo: dict = {}
    for a in range(n):
        for b in range(a + 1, n):
            for c in range(b + 1, n):
                if not (ok(a, b) and ok(a, c) and ok(b, c)):
                    continue
                if not (two_view(a, b) or two_view(a, c) or two_view(b, c)):
                    continue        # its votes would all go to pairs the cameras fixed, which ignore them
                closings = [_chained(pairs, a, b, c, memo=memo), _chained(pairs, b, a, c, memo=memo),
                            _chained(pairs, c, a, b, memo=memo)]
                closings = [x for x in closings if x is not None]
                if not closings:
                    continue
                good = max(closings) <= max_px
                for e in ((a, b), (a, c), (b, c)):
                    v = votes.setdefault(e, [0, 0])
                    v[0] += good
                    v[1] += 1
    out = dict(pairs)
    for (a, b), (n_good, n_eval) in votes.items():
        if pairs[(a, b)].source != "two-view":
            continue                      # cameras from the whole set are consistent by construction
        if n_eval >= 2 and n_good / n_eval < 0.5:
            g = dataclasses.replace(pairs[(a, b)], status=REJECTED, source="",
                                    reason=f"inconsistent with the other pairs: {n_eval - n_good} of {n_eval} "
                                           "triplets disagree (repeated texture?)")
            out[(a, b)] = g
            out[(b, a)] = g.reversed()
    return out


def uncertainty_gate(pairs: dict[tuple[int, int], PairGeometry], limit_px: float
                     ) -> dict[tuple[int, int], PairGeometry]:
    """Departure (default preset): reject two-view epipolar pairs whose lines are uncertain by more
    than `limit_px` (uncertainty_px, the spread of two half-data refits over the whole image).

    A two-view F fits its inliers, which often lie on one or two planes, and is free elsewhere;
    measured against the renderer's true cameras, most two-view F's that pass every two-view test
    and are still 5-40 px off on the scene have such a spread (issue "Geometry you can trust").
    Reconstruction pairs meet the same limit in apply_reconstruction. Returns the updated pairs
    (both orders); limit_px <= 0 changes nothing."""
    import dataclasses
    if not limit_px > 0:
        return pairs
    out = dict(pairs)
    for (a, b), g in pairs.items():
        if a < b and g.status == OK and g.source == "two-view" and not g.uncertainty_px <= limit_px:
            r = dataclasses.replace(g, status=REJECTED, source="",
                                    reason=f"epipolar lines too uncertain ({g.uncertainty_px:.1f} px > {limit_px:.1f} px: "
                                           "F refitted on either half of the matches moves them)")
            out[(a, b)] = r
            out[(b, a)] = r.reversed()
    return out


def support_sets(pairs: dict[tuple[int, int], PairGeometry], n: int) -> list[list[int]]:
    """For each reference index, the sorted indices of its admitted support images."""
    return [sorted(j for j in range(n) if j != i and pairs[(i, j)].ok) for i in range(n)]


def cap_supports(supports: list[list[int]], pairs: dict, k: int, centres: np.ndarray | None = None
                 ) -> list[list[int]]:
    """At most k supports per reference (issue: large sets), chosen greedily for geometry quality
    and viewpoint diversity, deterministically.

    Quality: log(1 + verified matches) minus the epipolar-line uncertainty in units of 4 px.
    Diversity (when camera centres (n, 3) are known, NaN rows for unregistered photos): each next
    support gains twice the smallest angle (radians, seen from the reference) to those chosen.
    The result keeps each reference's supports in index order.
    """
    out = []
    for i, sup in enumerate(supports):
        if len(sup) <= k:
            out.append(list(sup))
            continue
        q = {}
        for j in sup:
            g = pairs[(i, j)]
            unc = g.uncertainty_px if np.isfinite(g.uncertainty_px) else 4.0
            q[j] = np.log1p(g.n_inliers) - unc / 4.0
        d = {}
        if centres is not None and np.all(np.isfinite(centres[i])):
            for j in sup:
                v = centres[j] - centres[i]
                if np.all(np.isfinite(v)) and np.linalg.norm(v) > 0:
                    d[j] = v / np.linalg.norm(v)
        chosen: list[int] = []
        left = list(sup)
        nearest = {j: np.inf for j in d}      # each one's smallest angle to those chosen, kept up to date
        while left and len(chosen) < k:
            def score(j):
                div = 2.0 * nearest[j] if j in d and np.isfinite(nearest[j]) else 0.0
                return (q[j] + div, -j)
            best = max(left, key=score)
            chosen.append(best)
            left.remove(best)
            if best in d:
                for j in left:
                    if j in d:
                        nearest[j] = min(nearest[j], np.arccos(np.clip(d[j] @ d[best], -1, 1)))
        out.append(sorted(chosen))
    return out
