"""The inspector's views as pictures and numbers, from a (partial) run: pure, no viser.

Each function reads a `SetResult` snapshot and a tab's `Settings`; maps come from model.TermCache
(the pipeline's Eq. 2 / Eq. 3 functions), evidence from pipeline.explain.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from pipeline.aggregate import cumulative_dynamic, remap
from pipeline.explain import PixelEvidence, explain_pixel
from pipeline.geometry import clip_line
from pipeline.peer import TAU, median_difference
from pipeline.run import SetResult

from . import render
from .model import Settings, TermCache, dynamic_prob, usable_supports

TILE = 200          # width of a per-support or sweep tile, px
EVIDENCE_TILE = 183  # width of a support's small evidence picture (two per row)


def main_view(snap: SetResult | None, rgb: np.ndarray, settings: Settings, layers: render.Layers,
              terms: TermCache, gt: np.ndarray | None = None, pixel: np.ndarray | None = None
              ) -> tuple[np.ndarray, np.ndarray | None]:
    """The reference with its overlays: ((h, w, 3) uint8, P_dynamic (h, w) float32 or None).

    gt: (h, w) bool at working resolution; pixel: (2,) the explained pixel, marked with a cross.
    """
    dyn = dynamic_prob(snap, settings, terms) if snap is not None else None
    img = render.overlay(rgb, dyn, settings.threshold, layers, gt)
    if pixel is not None:
        render.draw_cross(img, pixel, (255, 255, 255), size=9, thickness=2)
    return img, dyn


# ----------------------------------------------------------------------------- what the map says
@dataclass(frozen=True)
class Notice:
    """One line about the map on screen: `empty` (nothing above the threshold) or `doubtful`."""

    text: str
    empty: bool = False
    doubtful: bool = False


def map_notice(stem: str, dyn: np.ndarray | None, threshold: float, n_supports: int) -> Notice:
    """Says so when the map marks nothing (with its range), nearly everything, rests on one
    support, or is mostly without evidence (P_dynamic near 0.5)."""
    if dyn is None:
        return Notice("")
    lo, hi = float(dyn.min()), float(dyn.max())
    marked = float((dyn > threshold).mean())
    doubts = []
    if marked > 0.5:
        doubts.append(f"{marked:.0%} of the photo is marked moving")
    if n_supports == 1:
        doubts.append("the map rests on a single support")
    neutral = float((np.abs(dyn - 0.5) < 0.03).mean())
    if neutral > 0.5:
        doubts.append(f"{neutral:.0%} of the photo has no evidence (P_dynamic ≈ 0.5)")
    text = []
    if marked == 0.0:
        text.append(f"**Nothing is marked in {stem}**: P_dynamic here is {lo:.2f}–{hi:.2f}, all at or below the "
                    f"threshold {threshold:.2f}.")
    if doubts:
        text.append(f"**Doubtful**: {'; '.join(doubts)}.")
    return Notice(" ".join(text), empty=marked == 0.0, doubtful=bool(doubts))


# ----------------------------------------------------------------------------- supports and sweep
def support_mosaic(snap: SetResult, settings: Settings, terms: TermCache, stems: list[str],
                   columns: int = 2) -> np.ndarray:
    """P(x|I_s) of every ready support of the reference as small heat maps under their key; blue =
    matched (static), red = no match. Supports switched off are greyed."""
    p = settings.params()
    i = settings.ref
    tiles = []
    for j in snap.supports[i]:
        if (i, j) not in snap.pair_results:
            continue
        mp = terms.match_prob(snap, i, j, p)
        kind = {"homography": "H", "peer": "H"}.get(snap.kind(i, j), "F")      # without loading the pair
        # drawn as 1 - P so the colours read like the main map: blue = matched (static), red = no match
        tiles.append(render.label(render.fit(render.heat(1.0 - mp), TILE), stems[j], f"{kind} · match {mp.mean():.2f}",
                                  dim=j not in settings.supports))
    if not tiles:
        return render.message("No support is ready for this reference yet.")
    grid = render.mosaic(tiles, columns)
    return render.stack([render.colour_key(grid.shape[1], "mismatch"), grid])


@dataclass(frozen=True)
class SweepView:
    """Fig. 5: P_dynamic after the first k usable supports. supports: (K,) their indices;
    maps: K (h, w) float32 maps; the last equals the main view's map."""

    supports: tuple[int, ...]
    maps: tuple[np.ndarray, ...]


def sweep(snap: SetResult, settings: Settings, terms: TermCache) -> SweepView:
    sups = usable_supports(snap, settings)
    p = settings.params()
    if p.sweep.enabled or p.geometry.peer_homography:      # not a running product: each prefix anew
        maps = [dynamic_prob(snap, dataclasses.replace(settings, supports=tuple(sups[:k])), terms)
                for k in range(1, len(sups) + 1)]
        return SweepView(tuple(sups), tuple(maps))
    probs = [terms.match_prob(snap, settings.ref, j, p) for j in sups]
    maps = [snap.refine_dynamic(settings.ref, d, p) for d in cumulative_dynamic(probs, p.aggregate)]
    return SweepView(tuple(sups), tuple(maps))


def sweep_mosaic(view: SweepView, stems: list[str], threshold: float, scores: list[float] | None = None,
                 columns: int = 2) -> np.ndarray:
    tiles = []
    for k, (j, m) in enumerate(zip(view.supports, view.maps), start=1):
        sub = f"J {scores[k - 1]:.2f}" if scores else f"{(m > threshold).mean():.0%} marked"
        img = render.overlay(np.zeros((*m.shape, 3), np.uint8), m, threshold,
                             render.Layers(photo=False, heat=True, mask=True, gt=False))
        tiles.append(render.label(render.fit(img, TILE), f"{k}: +{stems[j]}", sub))
    if not tiles:
        return render.message("No support is ready for this reference yet.")
    grid = render.mosaic(tiles, columns)
    return render.stack([render.colour_key(grid.shape[1], "dynamic", threshold=threshold, outlines=(True, False)),
                         grid])


# ----------------------------------------------------------------------------- one pixel
@dataclass(frozen=True)
class FusionRow:
    """One line of the fusion at a pixel. sup: the support (None for the depth cue and the mean);
    kind: the pair's kind, "mean" (the sum divided by the supports that see the point) or
    "depth" (the depth cue); p: its
    P(x|I_s) (for the depth cue: the fused match probability; for the peer baseline: its
    P_dynamic alone); q: p remapped (§3.2; NaN where not used); vote: its log-odds for
    "moving" (NaN for the peer baseline, a median); total: the running sum after it."""

    sup: int | None
    name: str
    kind: str
    p: float
    q: float
    vote: float
    total: float


@dataclass(frozen=True)
class Fusion:
    """How the supports' answers at a pixel make its P_dynamic.

    method: "votes" (Eq. 3 as a sum of log-odds, plus the depth cue for `default`) or "median"
    (the peer baseline: the median colour difference); total: the sum of the votes;
    scale, offset: P_raw = 1 / (1 + exp(-scale * (total + offset))) (1 and 0 without the
    calibration); p_raw: P_dynamic from the formula, before the refinement; p_map: the value on
    the map (after the optional guided filter); threshold_at: the total at which P_raw equals
    the threshold; speaks: some support saw the point (else P_raw is 0.5, no evidence);
    plane_vote: the plane-aligned difference's log-odds for "moving", added last (after the guided
    filter; NaN without the cue), plane_diff its median colour difference at the pixel (NaN where no
    support covers it), p_before_plane the value it was added to."""

    method: str
    rows: tuple[FusionRow, ...]
    total: float
    scale: float
    offset: float
    p_raw: float
    p_map: float
    refined: bool
    threshold_at: float
    speaks: bool = True
    plane_vote: float = float("nan")
    plane_diff: float = float("nan")
    p_before_plane: float = float("nan")


def _logit(t: float) -> float:
    t = float(np.clip(t, 1e-6, 1 - 1e-6))
    return float(np.log(t / (1 - t)))


def fusion(snap: SetResult, settings: Settings, terms: TermCache, dyn: np.ndarray, xy: np.ndarray,
           stems: list[str]) -> Fusion:
    """The fusion at pixel xy (working resolution) with the same cached terms as the map: each
    support's Eq. 3 term (model.TermCache.term), negated to a vote for "moving", the depth cue's
    weighted log-odds (SetResult.sweep_log_odds), their running sum, and the calibrated logistic
    that turns the sum into P_dynamic (model.dynamic_prob does the same on whole maps)."""
    i = settings.ref
    p = settings.params()
    u, v = int(round(xy[0])), int(round(xy[1]))
    sups = usable_supports(snap, settings)
    p_map = float(dyn[v, u])
    refined = p.aggregate.refine_radius_frac > 0
    rows = []
    if p.geometry.peer_homography:
        diffs = []
        for j in sups:
            d = float(snap.pair_results[(i, j)].diff[v, u])
            diffs.append(d)
            pj = float(1.0 - np.exp(-d / TAU)) if np.isfinite(d) else float("nan")
            rows.append(FusionRow(j, stems[j], "peer", pj, float("nan"), float("nan"), float("nan")))
        with np.errstate(all="ignore"):
            import warnings
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                med = float(np.nanmedian(diffs)) if diffs else float("nan")
        p_raw = float(1.0 - np.exp(-med / TAU)) if np.isfinite(med) else 0.5
        return Fusion("median", tuple(rows), med, 1.0, 0.0, p_raw, p_map, refined, float("nan"))
    total, seen = 0.0, 0
    for j in sups:
        mp = float(terms.match_prob(snap, i, j, p)[v, u])
        vote = -float(terms.term(snap, i, j, p)[v, u])
        total += vote
        r = snap.pair_results[(i, j)]
        seen += bool(r.evidence[v, u] > 0.05)
        rows.append(FusionRow(j, stems[j], r.kind, mp, float(remap(np.float32(mp), *p.aggregate.remap)), vote, total))
    a = p.aggregate
    speaks = True
    if not p.sweep.enabled:          # Eq. 3 as published: the product over the supports
        scale, offset = 1.0, 0.0
    else:                            # SetResult.static_log_odds and dynamic_prob, at one pixel
        scale, offset = a.calib_scale, a.calib_offset
        if a.mean_terms:             # the supports' mean: comparable across photos
            mean = total / max(seen, 1)
            rows.append(FusionRow(None, f"÷ {max(seen, 1)} (mean)", "mean", float("nan"), float("nan"),
                                  mean - total, mean))
            total = mean
        if p.sweep.weight > 0:
            sw = snap.sweep_log_odds(i, sups, p)
            if sw is not None:
                lo = float(sw[v, u])
                vote = -p.sweep.weight * lo
                total += vote
                rows.append(FusionRow(None, "depth cue", "depth", float(1 / (1 + np.exp(-lo))), float("nan"),
                                      vote, total))
        speaks = bool(snap.has_evidence(i, sups, p)[v, u])
    p_raw = float(1.0 / (1.0 + np.exp(-scale * (total + offset)))) if speaks else 0.5
    plane_vote = plane_diff = p_before = float("nan")
    z = snap.plane_log_odds(i, sups, p)
    if z is not None:                # SetResult.with_plane_cue, at one pixel
        a = p.aggregate
        plane_vote = -a.plane_weight * float(z[v, u])
        plane_diff = float(median_difference([d[v:v + 1, u:u + 1] for d in snap.plane_diffs(i, sups)])[0, 0])
        q = min(max(p_map, 1e-6), 1 - 1e-6)
        p_before = float(1.0 / (1.0 + np.exp(-(np.log(q / (1 - q)) - plane_vote))))
    return Fusion("votes", tuple(rows), total, scale, offset, p_raw, p_map, refined,
                  _logit(settings.threshold) / scale - offset, speaks, plane_vote, plane_diff, p_before)


@dataclass(frozen=True)
class PixelReport:
    """Everything shown for a clicked pixel. values: P(x|I_s) per usable support (same order as
    evidence); dynamic: the aggregate P_dynamic at the pixel; depth_values: each support's match
    probability at the shared depth (NaN: not swept); fusion: how they add up."""

    xy: np.ndarray
    dynamic: float
    evidence: tuple[PixelEvidence, ...]
    values: tuple[float, ...]
    depth_values: tuple[float, ...] = ()
    fusion: Fusion | None = None
    ref: int = 0


def _peer_evidence(snap: SetResult, i: int, j: int, xy: np.ndarray) -> PixelEvidence:
    """The peer baseline's evidence at a pixel: where H puts it in the support, and whether the
    aligned support covers it."""
    pair = snap.pair_results[(i, j)]
    q = pair.H @ np.array([xy[0], xy[1], 1.0])
    u, v = int(round(xy[0])), int(round(xy[1]))
    seen = float(np.isfinite(pair.diff[v, u]))
    return PixelEvidence(i, j, "peer", np.asarray(xy, np.float64), seen, 0, None, point=q[:2] / q[2])


def explain(snap: SetResult, settings: Settings, terms: TermCache, dyn: np.ndarray, xy: np.ndarray,
            stems: list[str] | None = None) -> PixelReport:
    i = settings.ref
    p = settings.params()
    stems = stems or [ph.stem for ph in snap.photo_set.photos]
    u, v = int(round(xy[0])), int(round(xy[1]))
    sups = usable_supports(snap, settings)
    evs = tuple(_peer_evidence(snap, i, j, xy) if snap.kind(i, j) == "peer"
                else explain_pixel(snap, i, j, xy, sups) for j in sups)
    vals = tuple(float(terms.match_prob(snap, i, j, p)[v, u]) for j in sups)
    depth = tuple(float(m[v, u]) if (m := snap.depth_match_prob(i, j, sups, p)) is not None else float("nan")
                  for j in sups) if p.sweep.enabled else (float("nan"),) * len(sups)
    return PixelReport(np.asarray(xy, np.float64), float(dyn[v, u]), evs, vals, depth,
                       fusion(snap, settings, terms, dyn, xy, stems), i)


def _candidate_text(e: PixelEvidence) -> str:
    if e.kind == "peer":
        return "aligned by H"
    if e.patch is None or len(e.patch.cand_quads) == 0:
        return "no candidate"
    h = e.patch.sim_hog[e.patch.best_hog]
    c = e.patch.sim_color[e.patch.best_color]
    return f"HOG {h:.2f} · colour {c:.2f}"


def _scaled(pts, s: float) -> np.ndarray:
    """Working-resolution pixel coordinates (centres at integers) in a picture scaled by s."""
    return (np.asarray(pts, np.float64) + 0.5) * s - 0.5


def evidence_picture(snap: SetResult, e: PixelEvidence, width: int) -> np.ndarray:
    """The support photo at `width` px with where the pixel was searched, drawn at that scale:
    the epipolar line (yellow), the part of it the depth range allows (cyan) and the shared
    depth (cyan cross), or the homography point and its search window (yellow); the best HOG
    (green) and best colour (orange) candidates of the covering patch nearest the pixel."""
    rgb = snap.photo_set.photos[e.sup].rgb
    h, w = rgb.shape[:2]
    s = width / w
    img = np.ascontiguousarray(render.fit(rgb, width))
    t = max(1, int(round(width / 420)))            # line width in display pixels
    if e.strip is not None and np.all(np.isfinite(e.strip)):      # a band under the line
        render.draw_polyline(img, _scaled(e.strip, s), render.STRIP_RGB, 3 * t + 2, closed=False, outline=True)
    if e.line is not None:
        seg = clip_line(e.line, (h, w))
        if seg is not None:
            render.draw_polyline(img, _scaled(seg, s), render.LINE_RGB, t, closed=False)
    if e.window is not None:
        render.draw_polyline(img, _scaled(e.window, s), render.LINE_RGB, t, outline=True)
    if e.patch is not None and len(e.patch.cand_quads):
        render.draw_polyline(img, _scaled(e.patch.cand_quads[e.patch.best_color], s), render.COLOR_RGB, t + 1,
                             outline=True)
        render.draw_polyline(img, _scaled(e.patch.cand_quads[e.patch.best_hog], s), render.HOG_RGB, t + 1,
                             outline=True)
    if e.point is not None and np.all(np.isfinite(e.point)):
        render.draw_cross(img, _scaled(e.point, s), render.LINE_RGB, size=5 + 3 * t, thickness=t)
    if e.depth_point is not None and np.all(np.isfinite(e.depth_point)):
        render.draw_cross(img, _scaled(e.depth_point, s), render.STRIP_RGB, size=5 + 3 * t, thickness=t + 1)
    return img


def evidence_tiles(snap: SetResult, report: PixelReport, stems: list[str], width: int = EVIDENCE_TILE,
                   columns: int = 2) -> np.ndarray:
    """Each support with where the pixel was searched (evidence_picture), two per row."""
    tiles = [render.label(evidence_picture(snap, e, width), f"{stems[e.sup]}  P {val:.2f}", _candidate_text(e),
                          size=12)
             for e, val in zip(report.evidence, report.values)]
    return render.mosaic(tiles, columns) if tiles else render.message("No support is ready.")


def lines_legend(width: int, kinds: set[str], swept: bool, size: int = 13) -> np.ndarray:
    items = []
    if "epipolar" in kinds:
        items.append((render.LINE_RGB, "line", "where the point can lie (epipolar line)"))
    if swept:
        items += [(render.STRIP_RGB, "line", "the part its depth range allows"),
                  (render.STRIP_RGB, "cross", "the depth all supports agree on")]
    if kinds & {"homography", "peer"}:
        items.append((render.LINE_RGB, "cross", "where the homography puts it"))
    if "homography" in kinds:
        items.append((render.LINE_RGB, "box", "its search window"))
    if kinds & {"epipolar", "homography"}:
        items += [(render.HOG_RGB, "box", "best HOG (shape) match"), (render.COLOR_RGB, "box", "best colour match")]
    return render.legend(items, width, size)


def crops(snap: SetResult, report: PixelReport, e: PixelEvidence, width: int, size: int = 13) -> np.ndarray:
    """The reference patch beside what it was compared with in this support: the best HOG and
    best colour candidates, and the window at the shared depth, each enlarged, outlined and
    labelled with its score."""
    ref_rgb = snap.photo_set.photos[report.ref].rgb
    sup_rgb = snap.photo_set.photos[e.sup].rgb
    items = []          # (photo, centre, side, outline quad or None, colour, title, sub)
    patch = e.patch
    if patch is not None:
        q = patch.ref_quad
        side = 1.8 * float(np.max(q.max(axis=0) - q.min(axis=0)))
        items.append((ref_rgb, q.mean(axis=0), side, q, render.REF_RGB, "reference patch", "the point's patch"))
    else:
        side = 48.0
        items.append((ref_rgb, report.xy, side, None, render.REF_RGB, "reference", "the point"))
    if patch is not None and len(patch.cand_quads):
        for k, colour, name, sims in ((patch.best_hog, render.HOG_RGB, "best HOG", patch.sim_hog),
                                      (patch.best_color, render.COLOR_RGB, "best colour", patch.sim_color)):
            cq = patch.cand_quads[k]
            cside = max(side, 1.8 * float(np.max(cq.max(axis=0) - cq.min(axis=0))))
            val = sims[k]
            items.append((sup_rgb, cq.mean(axis=0), cside, cq, colour, name,
                          f"similarity {val:.2f}" if np.isfinite(val) else ""))
    elif e.kind == "peer" and e.point is not None:
        items.append((sup_rgb, e.point, side, None, render.LINE_RGB, "aligned by H", "same spot in the support"))
    else:
        items.append((None, None, 0, None, None, "no candidate", "out of the support's view"))
    if e.depth_point is not None and np.all(np.isfinite(e.depth_point)):
        win = snap.params.sweep.window / max(snap.params.sweep.scale, 1e-6)
        sq = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], np.float64) * win / 2 + e.depth_point
        dv = report.depth_values[report.evidence.index(e)] if report.depth_values else float("nan")
        items.append((sup_rgb, e.depth_point, side, sq, render.STRIP_RGB, "shared depth",
                      f"match {dv:.2f}" if np.isfinite(dv) else ""))
    gap = 8
    n = len(items)
    out = int(min(max(170, width // 5), 240, (width - gap * (n - 1)) / n))
    cells = []
    size = int(min(size, max(10, out / 11)))
    for photo, centre, side_, quad, colour, title, sub in items:
        if photo is None:
            img = np.full((out, out, 3), 235, np.uint8)
        else:
            img, A = render.crop(photo, centre, side_, out)
            img = np.ascontiguousarray(img)
            if quad is not None:
                render.draw_polyline(img, render.apply_affine(A, quad), colour, 2, outline=True)
            else:
                render.draw_cross(img, render.apply_affine(A, np.asarray(centre)[None])[0], colour, size=8,
                                  thickness=2)
        cap = render.put_text(np.full((size + 4, out, 3), 255, np.uint8), (2, 1), title, size, bold=True)
        sub_img = render.put_text(np.full((size + 4, out, 3), 255, np.uint8), (2, 1), sub, size - 1,
                                  colour=render.GREY_INK)
        cells.append(np.vstack([cap, img, sub_img]))
    row = np.full((cells[0].shape[0], out * n + gap * (n - 1), 3), 255, np.uint8)
    for k, c in enumerate(cells):
        row[:, k * (out + gap):k * (out + gap) + out] = c
    return row


def large_view(snap: SetResult, report: PixelReport, sup: int, stems: list[str], width: int) -> np.ndarray:
    """A support's evidence for the clicked pixel, big: a caption, the support photo at `width`
    px with the search drawn at display scale (evidence_picture), the crops (reference patch
    beside the best candidates), and a legend of the lines."""
    k = [e.sup for e in report.evidence].index(sup)
    e, val = report.evidence[k], report.values[k]
    size = int(np.clip(width / 70, 13, 20))
    kind = {"epipolar": "epipolar pair", "homography": "homography pair", "peer": "aligned by a homography"}[e.kind]
    says = "a match: says static" if val > 0.5 else ("no opinion" if val == 0.5 else "no match: says moving")
    head = render.paragraph(f"{stems[sup]}, a support of {stems[report.ref]} · {kind} · pixel "
                            f"({report.xy[0]:.0f}, {report.xy[1]:.0f}) · P(x|I_s) {val:.2f} ({says})", width, size,
                            bold=True)
    pic = evidence_picture(snap, e, width)
    swept = e.strip is not None
    parts = [head, pic, crops(snap, report, e, width, size),
             lines_legend(width, {e.kind}, swept, size)]
    return render.stack(parts, gap=6)


def after_the_sum(f: Fusion) -> list[tuple[str, float, float, bool]]:
    """The steps after the sum of votes, in the sum's units (the total whose P_raw would be the
    value reached): the guided filter ("smoothing", a neutral step: it is no vote) and the
    plane-aligned difference ("plane diff"), so that the chart ends at the map's value.
    (name, step, total after it, neutral); names short enough for the chart's label column."""
    if f.method != "votes" or not f.speaks:
        return []
    def as_total(p: float) -> float:
        return _logit(min(max(p, 1e-6), 1 - 1e-6)) / f.scale - f.offset
    plane = np.isfinite(f.plane_vote)
    out, total = [], f.total
    before = f.p_before_plane if plane else f.p_map
    if f.refined:
        out.append(("smoothing", as_total(before) - total, as_total(before), True))
        total = as_total(before)
    if plane:
        out.append(("plane diff", as_total(f.p_map) - total, as_total(f.p_map), False))
    return out


def threshold_at(f: Fusion, threshold: float) -> float:
    """The total of votes at which the fusion's P_dynamic (before smoothing) equals `threshold`."""
    return _logit(threshold) / f.scale - f.offset if f.method == "votes" else float("nan")


def _signed(x: float) -> str:
    return f"{x:+.2f}".replace("-", "−")


def verdict_markdown(report: PixelReport, ref_stem: str, threshold: float) -> str:
    u, v = report.xy
    verdict = "**marked moving**" if report.dynamic > threshold else "**not marked** (static)"
    return (f"**Pixel ({u:.0f}, {v:.0f})** of {ref_stem}: P_dynamic **{report.dynamic:.2f}**, {verdict} at the "
            f"threshold {threshold:.2f}.")


def fusion_markdown(report: PixelReport) -> str:
    """The fusion as a table that adds up: each support's P(x|I_s), remapped q, vote and the
    running sum, then the formula that turns the sum into P_dynamic."""
    f = report.fusion
    if f is None or not f.rows:
        return "No support is ready for this reference yet."
    lines = []
    if f.method == "votes":
        lines += ["| support | P(x\\|I_s) | q | vote | sum |", "|---|--:|--:|--:|--:|"]
        for r in f.rows:
            tag = {"epipolar": " (F)", "homography": " (H)"}.get(r.kind, "")
            pv = "–" if not np.isfinite(r.p) else f"{r.p:.2f}"
            q = "–" if not np.isfinite(r.q) else f"{r.q:.2f}"
            lines.append(f"| {r.name}{tag} | {pv} | {q} | {_signed(r.vote)} | {_signed(r.total)} |")
        if f.scale != 1.0 or f.offset != 0.0:
            formula = f"1 / (1 + e^(−{f.scale:.2f} × (sum {_signed(f.offset)})))"
        else:
            formula = "1 / (1 + e^(−sum))"
        plane = np.isfinite(f.plane_vote)
        shown = f.p_before_plane if plane else f.p_map
        if not f.speaks:
            lines += ["", "No support sees this point: no evidence, so P_dynamic = **0.50**."]
        else:
            lines += ["", f"P_dynamic = {formula} = **{f.p_raw:.2f}**"
                      + (f"; smoothed along the photo's edges (guided filter): **{shown:.2f}**."
                         if f.refined else ".")]
        if plane:
            seen = (f"their median colour difference here is {f.plane_diff:.1f}" if np.isfinite(f.plane_diff)
                    else "none of them covers this point (read as the peer's 0.5: mildly static)")
            lines += ["", f"Then the plane-aligned difference (each support aligned to this photo by the homography "
                      f"of its matches; {seen}) adds {_signed(f.plane_vote)} to the log-odds for moving "
                      f"({_signed(f.plane_vote / f.scale)} on the chart, in the sum's units): "
                      f"the map shows **{f.p_map:.2f}**."]
    else:
        lines += ["| support | colour difference | P alone |", "|---|--:|--:|"]
        for r in f.rows:
            d = -TAU * np.log(1 - r.p) if np.isfinite(r.p) and r.p < 1 else float("nan")
            lines.append(f"| {r.name} | {d:.1f} | {r.p:.2f} |" if np.isfinite(d) else f"| {r.name} | – | – |")
        lines += ["", f"P_dynamic = 1 − e^(−median / {TAU:.0f}) = 1 − e^(−{f.total:.1f} / {TAU:.0f}) = "
                  f"**{f.p_raw:.2f}**" + (f"; after the guided filter **{f.p_map:.2f}**." if f.refined else ".")]
    return "\n".join(lines)


def evidence_markdown(report: PixelReport, stems: list[str]) -> str:
    """What each support found: evidence share, the best candidates' similarities, and its match
    at the shared depth."""
    if not report.evidence or all(e.kind == "peer" for e in report.evidence):
        return ""           # the peer baseline compares aligned colours: no candidates, no depth
    lines = ["| support | evidence | HOG | colour | shared depth |", "|---|--:|--:|--:|--:|"]
    depth_vals = report.depth_values or (float("nan"),) * len(report.values)
    for e, dv in zip(report.evidence, depth_vals):
        if e.patch is not None and len(e.patch.cand_quads):
            bh, bc = e.patch.sim_hog[e.patch.best_hog], e.patch.sim_color[e.patch.best_color]
            bh = f"{bh:.2f}" if np.isfinite(bh) else "–"
            bc = f"{bc:.2f}" if np.isfinite(bc) else "–"
        else:
            bh = bc = "–"
        kind = " (F)" if e.kind == "epipolar" else " (H)"
        dtxt = "–" if not np.isfinite(dv) else f"{dv:.2f}"
        lines.append(f"| {stems[e.sup]}{kind} | {e.evidence:.0%} | {bh} | {bc} | {dtxt} |")
    return "\n".join(lines)


def report_markdown(report: PixelReport, stems: list[str], ref_stem: str, threshold: float) -> str:
    """The pixel's verdict, the fusion as a table that adds up, and the evidence per support."""
    return "\n\n".join(t for t in (verdict_markdown(report, ref_stem, threshold), fusion_markdown(report),
                                     evidence_markdown(report, stems)) if t)


HELP = """
**How the supports' answers add up** (the chart above and the first table):

- **P(x|I_s)**: how well support photo *s* found a look-alike of the patch around this point,
  somewhere along the line where the point can lie in *s* (its epipolar line). 1 = a perfect
  match: seen from *s* the point looks static; 0 = nothing alike: it looks moving (§3.1, Eq. 2).
- **q**: P(x|I_s) squeezed into the remap range (0.3–0.7 in the paper), so that no single support
  decides alone (§3.2).
- **vote**: ln((1 − q) / q), how strongly the support says *moving* (positive, red bar) or *static*
  (negative, blue bar); 0 is no opinion. Eq. 3 multiplies probabilities, which is the same as
  adding these votes (§3.2).
- **depth cue** (`default` preset): what all supports say together at the one depth where they
  agree best (a plane sweep over the reconstruction's depth range; for a photo without a camera,
  over a pencil of planes its supports' F's share, whose hypotheses have no depth in metres); its
  vote is added like a support's (at half weight where it rests on one pencil support alone, whose
  F no other support checks).
- **sum**: the running total of the votes. The formula under the table turns it into P_dynamic
  (for `default` with a scale and offset calibrated on rendered sets). Right of the dashed
  threshold line in the chart means *marked moving*.
- **F / H**: an epipolar pair (searched along the epipolar line) or a homography pair (the
  support is aligned by one homography: a shot from the same spot, or a distant or flat scene).

**The evidence table**:

- **evidence 42 %**: how much of this point's weight (Eq. 2 averages the patches that cover it:
  nine, from three fans of strips; three where a depth-swept pair searches one fan in `default`)
  comes from patches that had any candidate in the support's view. 100 % = fully seen;
  0 % = the support does not see this point, and its P(x|I_s) is then the *No evidence* choice
  (0.5, no opinion, in `default`; 0, no match, in `paper`).
- **HOG / colour**: the similarity of the best candidate (Eq. 1) of the covering patch nearest
  the point: HOG compares shapes (gradients), colour compares hue–saturation histograms
  (§3.1.2).
- **shared depth**: this support's match probability at the depth all supports agreed on.
- **–**: no value: the patch had no candidate (out of the support's view), or the pair is not in
  the depth sweep (no camera for it).
"""


# ----------------------------------------------------------------------------- the Geometry view
def geometry_key(width: int, size: int = 13) -> np.ndarray:
    """The Geometry view's legend: what the frames' and lines' colours say (the epipolar-line
    uncertainty classes of geometry_view), the reference, the other photos and the ray."""
    from .geometry_view import OTHER_RGB, REFERENCE_RGB, SUPPORT_RGB, UNCERTAINTY_CLASSES, UNKNOWN_RGB
    title = render.paragraph("The clicked point's line in each support: how sure its geometry is (1 σ of the "
                             "epipolar line, px)", width, size, bold=True)
    items = [(c, "line", words) for _, c, words in UNCERTAINTY_CLASSES] + [(UNKNOWN_RGB, "line", "unknown")]
    items += [(REFERENCE_RGB, "line", "the point's viewing ray"), (REFERENCE_RGB, "box", "the reference"),
              (SUPPORT_RGB, "box", "a support"), (OTHER_RGB, "box", "not a support")]
    return render.stack([title, render.legend(items, width, size)], gap=0)


def geometry_markdown(set_name: str, stems: list[str], ref: int, cams, pairs: dict, supports: list[int],
                      lines: list | None = None) -> str:
    """What the Geometry view shows, how to use it, and each support's geometry: its source
    (reconstruction, two-view, homography) and the uncertainty of its lines (1 σ, px)."""
    from .geometry_view import uncertainty_words
    n_cam = int(cams.registered.sum())
    head = (f"**Geometry of {set_name}**: {n_cam} of {len(stems)} photos have a camera from the set's "
            f"reconstruction, with {len(cams.points)} sparse 3-D points (mean reprojection error "
            f"{cams.mean_reproj_px:.2f} px). Drag to turn, scroll to zoom. "
            f"**Click the reference's picture ({stems[ref]}, black frame)**: its viewing ray is drawn, and in every "
            "support the line where that point can lie (its epipolar line; a cross for a homography pair).")
    if not cams.registered[ref]:
        head += f"\n\n**{stems[ref]} has no camera** ({cams.reasons[ref]}): no ray to draw; its pairs use two-view geometry."
    drawn = {ln.sup: ln for ln in (lines or [])}
    rows = ["| support | geometry | uncertainty |", "|---|---|--:|"]
    for j in supports:
        g = pairs.get((ref, j))
        if g is None:
            continue
        source = g.source or "rejected"
        if not cams.registered[j]:
            source += " (no camera)"
        elif j in drawn and drawn[j].kind == "epipolar" and drawn[j].segment is None:
            source += " (line out of view)"
        rows.append(f"| {stems[j]} | {source} | {uncertainty_words(g.uncertainty_px)} |")
    return head + "\n\n" + "\n".join(rows)
