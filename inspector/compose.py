"""The inspector's views as pictures and numbers, from a (partial) run: pure, no viser.

Each function reads a `SetResult` snapshot and a tab's `Settings`; maps come from model.TermCache
(the pipeline's Eq. 2 / Eq. 3 functions), evidence from pipeline.explain.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from pipeline.aggregate import cumulative_dynamic
from pipeline.geometry import clip_line
from pipeline.explain import PixelEvidence, explain_pixel
from pipeline.run import SetResult

from . import render
from .model import Settings, TermCache, dynamic_prob, usable_supports

TILE = 200          # width of a per-support or sweep tile, px
EVIDENCE_TILE = 380


def main_view(snap: SetResult | None, rgb: np.ndarray, settings: Settings, layers: render.Layers,
              terms: TermCache, gt: np.ndarray | None = None, pixel: np.ndarray | None = None
              ) -> tuple[np.ndarray, np.ndarray | None]:
    """The reference with its overlays: ((h, w, 3) uint8, P_dynamic (h, w) float32 or None).

    gt: (h, w) bool at working resolution; pixel: (2,) the explained pixel, marked with a cross.
    """
    dyn = dynamic_prob(snap, settings, terms) if snap is not None else None
    img = render.overlay(rgb, dyn, settings.threshold, layers, gt)
    if pixel is not None:
        render.draw_cross(img, pixel, (255, 255, 255), size=9)
    return img, dyn


def support_mosaic(snap: SetResult, settings: Settings, terms: TermCache, stems: list[str],
                   columns: int = 2) -> np.ndarray:
    """P(x|I_s) of every ready support of the reference as small heat maps; blue = matched
    (static), red = no match. Supports switched off are greyed."""
    p = settings.params()
    i = settings.ref
    tiles = []
    for j in snap.supports[i]:
        if (i, j) not in snap.pair_results:
            continue
        mp = terms.match_prob(snap, i, j, p)
        kind = "H" if snap.pair_results[(i, j)].kind == "homography" else "F"
        # drawn as 1 - P so the colours read like the main map: blue = matched (static), red = no match
        tiles.append(render.label(render.fit(render.heat(1.0 - mp), TILE), stems[j], f"{kind} match {mp.mean():.2f}",
                                  dim=j not in settings.supports))
    return render.mosaic(tiles, columns)


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
        sub = f"J {scores[k - 1]:.2f}" if scores else f"{(m > threshold).mean():.0%} > thr"
        img = render.overlay(np.zeros((*m.shape, 3), np.uint8), m, threshold,
                             render.Layers(photo=False, heat=True, mask=True, gt=False))
        tiles.append(render.label(render.fit(img, TILE), f"k={k}: +{stems[j]}", sub))
    return render.mosaic(tiles, columns)


@dataclass(frozen=True)
class PixelReport:
    """Everything shown for a clicked pixel. values: P(x|I_s) per usable support (same order as
    evidence); dynamic: the aggregate P_dynamic at the pixel."""

    xy: np.ndarray
    dynamic: float
    evidence: tuple[PixelEvidence, ...]
    values: tuple[float, ...]
    depth_values: tuple[float, ...] = ()


def explain(snap: SetResult, settings: Settings, terms: TermCache, dyn: np.ndarray, xy: np.ndarray
            ) -> PixelReport:
    i = settings.ref
    p = settings.params()
    u, v = int(round(xy[0])), int(round(xy[1]))
    sups = usable_supports(snap, settings)
    evs = tuple(explain_pixel(snap, i, j, xy, sups) for j in sups)
    vals = tuple(float(terms.match_prob(snap, i, j, p)[v, u]) for j in sups)
    depth = tuple(float(m[v, u]) if (m := snap.depth_match_prob(i, j, sups, p)) is not None else float("nan")
                  for j in sups)
    return PixelReport(np.asarray(xy, np.float64), float(dyn[v, u]), evs, vals, depth)


def _candidate_text(e: PixelEvidence) -> str:
    if e.patch is None or len(e.patch.cand_quads) == 0:
        return "no candidate"
    h = e.patch.sim_hog[e.patch.best_hog]
    c = e.patch.sim_color[e.patch.best_color]
    return f"HOG {h:.2f}  colour {c:.2f}"


def evidence_tiles(snap: SetResult, report: PixelReport, stems: list[str]) -> np.ndarray:
    """Each support image with where the pixel was searched (the epipolar line, or the
    homography point and its search window, yellow) and the dominant patch's best candidates:
    HOG green, colour orange."""
    tiles = []
    for e, val in zip(report.evidence, report.values):
        img = snap.photo_set.photos[e.sup].rgb.copy()
        h, w = img.shape[:2]
        if e.line is not None:
            seg = clip_line(e.line, (h, w))
            if seg is not None:
                render.draw_polyline(img, seg, render.LINE_RGB, 1, closed=False)
        if e.window is not None:
            render.draw_polyline(img, e.window, render.LINE_RGB, 1)
        if e.patch is not None and len(e.patch.cand_quads):
            render.draw_polyline(img, e.patch.cand_quads[e.patch.best_color], render.COLOR_RGB, 2)
            render.draw_polyline(img, e.patch.cand_quads[e.patch.best_hog], render.HOG_RGB, 2)
        if e.point is not None:
            render.draw_cross(img, e.point, render.LINE_RGB)
        if e.strip is not None and np.all(np.isfinite(e.strip)):      # the part of the line the depths allow
            render.draw_polyline(img, e.strip.astype(np.float32), render.STRIP_RGB, 3, closed=False)
        if e.depth_point is not None and np.all(np.isfinite(e.depth_point)):
            render.draw_cross(img, e.depth_point, render.STRIP_RGB, size=9)
        tiles.append(render.label(render.fit(img, EVIDENCE_TILE), f"{stems[e.sup]}  P(x|I_s) {val:.2f}",
                                  _candidate_text(e)))
    return render.mosaic(tiles, 1)


def report_markdown(report: PixelReport, stems: list[str], ref_stem: str, threshold: float) -> str:
    """The pixel's numbers as a table (what the bar chart and the tiles show)."""
    u, v = report.xy
    verdict = "dynamic" if report.dynamic > threshold else "static"
    lines = [f"**Pixel ({u:.0f}, {v:.0f})** of {ref_stem}: P_dynamic **{report.dynamic:.2f}** "
             f"({verdict} at {threshold:.2f})", "",
             "| support | pair | P(x\\|I_s) | at the shared depth | evidence | best HOG | best colour |",
             "|---|---|---|---|---|---|---|"]
    depth_vals = report.depth_values or (float("nan"),) * len(report.values)
    for e, val, dv in zip(report.evidence, report.values, depth_vals):
        if e.patch is not None and len(e.patch.cand_quads):
            bh = f"{e.patch.sim_hog[e.patch.best_hog]:.2f}"
            bc = f"{e.patch.sim_color[e.patch.best_color]:.2f}"
        else:
            bh = bc = "–"
        kind = "homography" if e.kind == "homography" else "epipolar"
        dtxt = "–" if not np.isfinite(dv) else f"{dv:.2f}"
        lines.append(f"| {stems[e.sup]} | {kind} | {val:.2f} | {dtxt} | {e.evidence:.0%} | {bh} | {bc} |")
    if not report.evidence:
        lines.append("| (no support is ready) | | | | | | |")
    return "\n".join(lines)
