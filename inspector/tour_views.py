"""The guided tour's steps: their words and their pictures, from a (partial) run. Pure, no viser.

Seven steps walk through the method of Dafni, Moses & Avidan on the set at hand (README, "Tour").
Every picture is drawn from what the pipeline computed and the inspector already shows: the
pairs' matches and F / H (support.PairGeometry), the reference strips and their support strips
(matching.PairResult), the candidates of the clicked point's patch (pipeline.explain via
compose.explain), the per-support maps P(x|I_s) (model.TermCache), the map on screen, the
support sweep and the fusion chart the Pixel and Sweep tabs publish, and the Jaccard score
(model.score). Nothing is estimated here.

A step's picture is a `Picture`: the RGB image and, when the reference photo is part of it,
where (so that a click on it picks a reference pixel, as in the plain view). A `Look` says how
the picture will be seen: the canvas's aspect (a step's two panels go side by side or one above
the other, whichever shows them larger there: two landscape photos side by side fill a narrow
canvas's width and leave most of its height empty) and a text scale (presenter mode's larger
type, also in the pictures).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from pipeline.evaluate import THRESHOLDS
from pipeline.geometry import clip_line
from pipeline.patches import ref_frames

from . import compose, render

WIDTH = 720            # a picture beside another in a step, px
HEIGHT = 560           # two photos side by side, px
MATCH_RGB = (40, 200, 70)


@dataclass(frozen=True)
class Step:
    key: str
    title: str
    text: str


STEPS = (
    Step("photos", "The photos and where they were taken",
         "These photos show one scene, taken by different people from different places a few seconds apart "
         "(a CrowdCam set, §1). We look for what moved in one of them, the **reference** (black frame). Every "
         "other photo whose geometry with it can be trusted is a **support** (§3); the others are left out."),
    Step("pair", "One pair: a point becomes a line",
         "Features found in both photos (green dots) fix how the two cameras see the scene: the pair's "
         "*epipolar geometry* (§3; implementation details in §4). A point of the reference may lie at any "
         "depth along its viewing ray, so in the support it can only be somewhere on one line, its "
         "**epipolar line** (yellow). **Click a point of the reference** to see its line."),
    Step("strips", "Strips, not lines",
         "One pixel is too little to compare, so the reference is cut into thin wedges between epipolar "
         "lines that fan out from the epipole, and each wedge into overlapping patches (§3.1.1). A wedge "
         "(a **strip**, filled) lies between two lines whose partners in the support bound the matching "
         "strip (blue): a static patch can only be found in there. Its patch is outlined in white."),
    Step("candidates", "Searching the strip",
         "Every candidate patch along the support's strip, in 3 widths, is compared with the reference "
         "patch by shape (HOG) and by colour (hue–saturation histogram) (§3.1.2, Eq. 1). Only the best "
         "similarity counts: a static point has a look-alike somewhere on its strip, a moved one usually "
         "has none. The chart shows the similarity along the strip, the best candidates boxed."),
    Step("support_map", "One support's answer",
         "The best similarities of the patches that cover a pixel, weighted (HOG 2, colour 1) and averaged, "
         "give P(x|I_s): how likely the pixel is static and seen in this support (§3.1.3, Eq. 2). "
         "**Blue: a match, red: none.** Red also appears where the point is hidden or out of view in this "
         "support: one support alone cannot tell."),
    Step("fusion", "Asking all the supports",
         "Like witnesses seen from different places, the supports' answers are combined (§3.2, Eq. 3): each "
         "is squeezed into 0.3–0.7 so that no single photo decides, then they are multiplied. What one "
         "support cannot see, the others can; a point none of them matches stays red. The tiles add the "
         "supports one by one (the paper's Fig. 5); the chart adds up the votes at the clicked point."),
    Step("result", "The result against the truth",
         "Points whose P_dynamic is above the threshold are marked moving (red outline). Where the set has a "
         "ground truth drawn by hand (green outline), the **Jaccard** score measures the overlap, "
         "intersection over union: 1 is perfect (§4.2). The paper reports it at the best threshold per "
         "photo and per set; the chart shows it for every threshold."),
)


@dataclass(frozen=True)
class Look:
    """How a step's picture will be seen. aspect: the canvas's width / height (None: side by
    side, always); text: the scale of the pictures' type (1; presenter mode larger)."""

    aspect: float | None = None
    text: float = 1.0

    def t(self, size: int) -> int:
        """A type size of the pictures, scaled."""
        return max(8, int(round(size * self.text)))


PLAIN = Look()


def _shows(w: float, h: float, aspect: float) -> float:
    """How large a w x h picture is shown on a canvas of this aspect (relative units)."""
    return min(aspect / w, 1.0 / h)


def one_above(a_shape, beside_shape, under_shape, look: Look, extra_h: float = 0.0, gap: int = 12) -> bool:
    """True: the second panel goes under the first (shape `under_shape`), False: beside it
    (`beside_shape`), whichever shows the step larger on the look's canvas (extra_h: what goes
    under both, legends and keys, about)."""
    if look.aspect is None:
        return False
    beside = (a_shape[1] + gap + beside_shape[1], max(a_shape[0], beside_shape[0]) + extra_h)
    under = (max(a_shape[1], under_shape[1]), a_shape[0] + gap + under_shape[0] + extra_h)
    return _shows(*under, look.aspect) > _shows(*beside, look.aspect)


def arrange(a: np.ndarray, b: np.ndarray, under: bool, gap: int = 12) -> np.ndarray:
    """a and b side by side, or b under a (both left-aligned at the top: the reference's place
    in the picture is the same either way)."""
    return render.stack([a, b], gap=gap) if under else side_by_side(a, b, gap)


@dataclass(frozen=True)
class Picture:
    """A step's picture. ref_box: (x0, y0, scale) when the reference photo is drawn in it at
    `scale` with its top-left corner at (x0, y0), else None."""

    rgb: np.ndarray
    ref_box: tuple[float, float, float] | None = None

    def to_reference(self, cx: float, cy: float, size: tuple[int, int]) -> np.ndarray | None:
        """Picture pixel (cx, cy) as a working-resolution reference pixel (or None: not on it)."""
        if self.ref_box is None:
            return None
        x0, y0, s = self.ref_box
        u, v = (cx - x0 + 0.5) / s - 0.5, (cy - y0 + 0.5) / s - 0.5
        h, w = size
        if not (-0.5 <= u <= w - 0.5 and -0.5 <= v <= h - 0.5):
            return None
        return np.array([np.clip(u, 0, w - 1), np.clip(v, 0, h - 1)])


# ----------------------------------------------------------------------------- drawing helpers
def _sc(pts, s: float) -> np.ndarray:
    """Working pixels (centres at integers) in a picture scaled by s."""
    return (np.asarray(pts, np.float64) + 0.5) * s - 0.5


def _photo(rgb: np.ndarray, width: int) -> tuple[np.ndarray, float]:
    return np.ascontiguousarray(render.fit(rgb, width)), width / rgb.shape[1]


MIN_WIDTH = 600       # a photo with a colour key under it: narrower (a portrait shot) and the key's words do not fit


def _photo_h(rgb: np.ndarray, height: int, min_width: int = 0) -> tuple[np.ndarray, float]:
    """The photo at `height` px (two photos of a step side by side share their height), at
    least `min_width` px wide."""
    return _photo(rgb, max(1, min_width, round(rgb.shape[1] * height / rgb.shape[0])))


def _line(img: np.ndarray, line, size: tuple[int, int], s: float, colour, t: int) -> None:
    seg = clip_line(np.asarray(line, np.float64), size)
    if seg is not None:
        render.draw_polyline(img, _sc(seg, s), colour, t, closed=False, outline=True)


def _dots(img: np.ndarray, pts: np.ndarray, s: float, colour, r: int = 3) -> None:
    for x, y in _sc(pts, s) if len(pts) else []:
        cv2.circle(img, (int(round(x)), int(round(y))), r + 1, (20, 20, 20), -1, cv2.LINE_AA)
        cv2.circle(img, (int(round(x)), int(round(y))), r, colour, -1, cv2.LINE_AA)


def _cross(img: np.ndarray, xy, s: float, size: int = 12, ring: bool = True) -> None:
    """The clicked point: a white cross in a white ring, outlined in black (it must be found at a
    glance on a busy photo, across a room); no ring where the point's patch is drawn around it."""
    if xy is not None:
        c = _sc(xy, s)
        if ring:
            p, r = (int(round(c[0])), int(round(c[1]))), int(round(1.5 * size))
            cv2.circle(img, p, r, (0, 0, 0), 6, cv2.LINE_AA)
            cv2.circle(img, p, r, (255, 255, 255), 3, cv2.LINE_AA)
        render.draw_cross(img, c, (255, 255, 255), size=size, thickness=3)


def side_by_side(left: np.ndarray, right: np.ndarray, gap: int = 12) -> np.ndarray:
    h = max(left.shape[0], right.shape[0])
    out = np.full((h, left.shape[1] + gap + right.shape[1], 3), 255, np.uint8)
    out[:left.shape[0], :left.shape[1]] = left
    out[:right.shape[0], left.shape[1] + gap:] = right
    return out


def _labelled(img: np.ndarray, title: str, sub: str = "", look: Look = PLAIN) -> tuple[np.ndarray, int]:
    """A caption bar above the picture; returns the picture and the bar's height."""
    out = render.label(img, title, sub, size=look.t(18))
    return out, out.shape[0] - img.shape[0]


def _put(img: np.ndarray, *args, **kw) -> np.ndarray:
    """render.put_text, as a writable array (cv2 draws on it next)."""
    return np.array(render.put_text(img, *args, **kw))


def chart(series: list[tuple[np.ndarray, np.ndarray, tuple[int, int, int], str]], width: int, height: int,
          x_label: str, y_label: str, marks: list[tuple[float, float, tuple[int, int, int], str]] = (),
          x_range: tuple[float, float] | None = None, vline: tuple[float, str] | None = None,
          size: int = 15) -> np.ndarray:
    """A small line chart on white: series (x, y, colour, name) with dots, y in [0, 1]; marks:
    (x, y, colour, text) drawn as large rings with their text; vline: (x, text) a dashed line."""
    img = np.full((height, width, 3), 255, np.uint8)
    left, right, top, bottom = 52, 14, 12 + size + 8, 2 * size + 22
    pw, ph = width - left - right, height - top - bottom
    xs = np.concatenate([np.asarray(x, np.float64) for x, *_ in series]) if series else np.zeros(1)
    lo, hi = x_range if x_range is not None else (float(np.nanmin(xs)), float(np.nanmax(xs)))
    hi = hi if hi > lo else lo + 1.0
    X = lambda x: left + (np.asarray(x, np.float64) - lo) / (hi - lo) * pw
    Y = lambda y: top + (1.0 - np.clip(np.asarray(y, np.float64), 0, 1.05) / 1.05) * ph
    for gy in (0.0, 0.25, 0.5, 0.75, 1.0):
        y = int(round(float(Y(gy))))
        cv2.line(img, (left, y), (left + pw, y), (225, 225, 225), 1)
        img = _put(img, (left - 6, y), f"{gy:.2f}", size - 2, colour=render.GREY_INK, anchor="rm")
    cv2.rectangle(img, (left, top), (left + pw, top + ph), (120, 120, 120), 1)
    if vline is not None:
        x = int(round(float(X(vline[0]))))
        for y in range(top, top + ph, 8):
            cv2.line(img, (x, y), (x, min(y + 4, top + ph)), render.INK, 1)
        img = _put(img, (x + 4, top + 2), vline[1], size - 2, colour=render.INK)
    for x, y, colour, _ in series:
        x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
        ok = np.isfinite(x) & np.isfinite(y)
        pts = np.stack([X(x[ok]), Y(y[ok])], axis=1)
        if len(pts) > 1:
            cv2.polylines(img, [np.round(pts).astype(np.int32)], False, colour, 2, cv2.LINE_AA)
        for px, py in pts if len(pts) < 400 else []:
            cv2.circle(img, (int(round(px)), int(round(py))), 3, colour, -1, cv2.LINE_AA)
    boxes = []                                  # the marks' words, (x0, y0, x1, y1): no two on top of each other
    for x, y, colour, text in marks:
        if np.isfinite(x) and np.isfinite(y):
            p = (int(round(float(X(x)))), int(round(float(Y(y)))))
            cv2.circle(img, p, 9, render.INK, 3, cv2.LINE_AA)
            cv2.circle(img, p, 9, colour, 2, cv2.LINE_AA)
            tw = render.text_width(text, size - 1, True)
            right = p[0] + 12 + tw < width
            x0 = min(p[0] + 12, width - 4) - (0 if right else tw)
            for ty in (p[1] - size - 2, p[1] + 10, p[1] - 2 * size - 8, p[1] + size + 16):
                box = (x0, ty, x0 + tw, ty + size + 2)
                if not any(box[0] < b[2] and b[0] < box[2] and box[1] < b[3] and b[1] < box[3] for b in boxes):
                    break
            boxes.append(box)
            img = _put(img, (min(p[0] + 12, width - 4), ty), text, size - 1, bold=True, anchor="la" if right else "ra")
    img = _put(img, (left, 4), y_label, size, bold=True)
    img = _put(img, (left + pw // 2, height - size - 6), x_label, size, anchor="ma")
    img = _put(img, (left, top + ph + 4), f"{lo:.0f}" if hi - lo > 5 else f"{lo:.1f}", size - 2,
                          colour=render.GREY_INK)
    img = _put(img, (left + pw, top + ph + 4), f"{hi:.0f}" if hi - lo > 5 else f"{hi:.1f}", size - 2,
                          colour=render.GREY_INK, anchor="ra")
    x1 = width - right                          # the series' names, a legend at the top right
    for _, _, colour, name in reversed(series):
        if name:
            x1 -= render.text_width(name, size - 2) + 4
            img = _put(img, (x1, 4), name, size - 2)
            cv2.line(img, (x1 - 24, 4 + size // 2), (x1 - 4, 4 + size // 2), colour, 3)
            x1 -= 36
    return img


def _legend(items, width: int, look: Look = PLAIN) -> np.ndarray:
    return render.legend(items, width, look.t(17))


def _legend_h(look: Look, rows: int = 2) -> float:
    """About the height of a legend of `rows` rows (for one_above)."""
    return rows * (look.t(17) + 8) + 4


# ----------------------------------------------------------------------------- the steps' pictures
def photos_picture(photos, stems: list[str], ref: int, relation: list[str], columns: int | None = None,
                   tile: int = 420, look: Look = PLAIN) -> Picture:
    """Step 1 without cameras: every photo of the set, each captioned with what it is to the
    reference (relation[k]: "reference", "support · …", "rejected: …", …); the reference framed.
    Columns: the grid that shows the tiles largest on the look's canvas."""
    n = len(photos)
    if columns is None:
        h0, w0 = photos[0].rgb.shape[:2]
        th = tile * h0 / w0 + 2 * (look.t(18) + 7)
        aspect = look.aspect or 1.6
        columns = max(range(1, n + 1), key=lambda c: _shows(c * tile, np.ceil(n / c) * th, aspect))
    tiles = []
    for k, p in enumerate(photos):
        img = np.ascontiguousarray(render.fit(p.rgb, tile))
        if k == ref:
            cv2.rectangle(img, (0, 0), (img.shape[1] - 1, img.shape[0] - 1), render.INK, 10)
        tiles.append(render.label(img, stems[k] + (" (reference)" if k == ref else ""),
                                  "" if k == ref else relation[k], size=look.t(18), dim=relation[k].startswith(
                                      ("rejected", "not used"))))
    return Picture(render.mosaic(tiles, columns, gap=10))


def has_cameras(snap) -> bool:
    """The run placed cameras for the set (the `default` preset's reconstruction): step 1 shows
    them in 3-D."""
    cams = getattr(snap, "cameras", None) if snap is not None else None
    return cams is not None and cams.n_registered > 0


def no_cameras_words(snap, preset: str) -> str:
    """Why step 1 shows the photos side by side rather than their cameras in 3-D."""
    if snap is None:
        return ""
    if has_cameras(snap):
        return "Choose *Geometry (3-D)* as the main view to see where they were taken."
    if not snap.params.geometry.reconstruction:
        return (f"The `{preset}` preset has no cameras for the set (it relates each pair on its own, as the paper "
                "does), so the photos are shown side by side; the `default` preset shows where they were taken.")
    return "No camera could be placed for this set, so the photos are shown side by side."


def cameras_words(stems: list[str], ref: int, relation: list[str], cams) -> str:
    """Step 1 in 3-D: what the view shows, how to use it, and the photos left out and why (the
    photos themselves are in the panel, photos_strip)."""
    out = [k for k, r in enumerate(relation) if k != ref and not r.startswith("support")]
    none = [stems[k] for k in range(len(stems)) if not cams.registered[k]]
    text = ("Each pyramid is a camera where the set's reconstruction put it (ours; the paper treats each pair "
            "on its own): its tip is where the photo was taken, its base is the photo; the dots are 3-D points. "
            f"The reference **{stems[ref]}** is black, its supports blue-grey"
            + (", the photos left out light grey (" + "; ".join(f"{stems[k]}: {relation[k]}" for k in out) + ")"
               if out else "") + ".")
    if none:
        text += f" No camera for {', '.join(none)}" + (f" (the reference: {cams.reasons[ref]})"
                                                       if not cams.registered[ref] else "") + "."
    return text + (" **Drag to turn, scroll to zoom; click the reference's photo** to draw a point's viewing "
                   "ray (the next steps follow that point).")


def photos_strip(photos, stems: list[str], ref: int, relation: list[str], width: int, size: int = 15) -> np.ndarray:
    """Step 1 in 3-D, in the tour panel: the photos themselves, small, each named with what it is
    to the reference (the reference framed in black, the photos left out greyed), so that the
    names on the cameras can be put to the pictures."""
    n = len(photos)
    columns = 3 if n <= 9 else 4
    tile = (width - 6 * (columns - 1)) // columns
    box_h = round(0.7 * tile)                   # every photo inside the same box (some sets mix portrait shots)
    tiles = []
    for k, p in enumerate(photos):
        h, w = p.rgb.shape[:2]
        sc = min(tile / w, box_h / h)
        small = cv2.resize(p.rgb, (max(1, round(w * sc)), max(1, round(h * sc))), interpolation=cv2.INTER_AREA)
        if k == ref:
            cv2.rectangle(small, (0, 0), (small.shape[1] - 1, small.shape[0] - 1), render.INK, 6)
        img = np.full((box_h, tile, 3), 255, np.uint8)
        x0, y0 = (tile - small.shape[1]) // 2, (box_h - small.shape[0]) // 2
        img[y0:y0 + small.shape[0], x0:x0 + small.shape[1]] = small
        role = "reference" if k == ref else ("support" if relation[k].startswith("support") else "left out")
        tiles.append(render.label(img, stems[k], role, size=size, dim=role == "left out"))
    return render.mosaic(tiles, columns, gap=6)


def cameras_key(width: int, size: int = 17) -> np.ndarray:
    """Step 1 in 3-D: what the colours of the Geometry view say (its frames and lines,
    geometry_view's colours)."""
    from .geometry_view import OTHER_RGB, REFERENCE_RGB, SUPPORT_RGB, UNCERTAINTY_CLASSES
    items = [(REFERENCE_RGB, "box", "the reference's camera and photo"), (SUPPORT_RGB, "box", "a support"),
             (OTHER_RGB, "box", "left out"), (REFERENCE_RGB, "line", "a clicked point's viewing ray"),
             (UNCERTAINTY_CLASSES[0][1], "line", "its epipolar line in a support: sure"),
             (UNCERTAINTY_CLASSES[1][1], "line", "±2–6 px"), (UNCERTAINTY_CLASSES[2][1], "line", "unsure")]
    return render.legend(items, width, size)


def pair_picture(ref_rgb: np.ndarray, sup_rgb: np.ndarray, g, pixel: np.ndarray | None, ref_name: str,
                 sup_name: str, look: Look = PLAIN) -> Picture:
    """Step 2: the reference and one support side by side with the pair's matched features
    (inliers, green) and, for the clicked pixel, its epipolar line F x (yellow) in the support
    (or, for a homography pair, the point H x)."""
    a, s = _photo_h(ref_rgb, HEIGHT)
    b, t = _photo_h(sup_rgb, HEIGHT)
    _dots(a, g.inliers_ref, s, MATCH_RGB)
    _dots(b, g.inliers_sup, t, MATCH_RGB)
    _cross(a, pixel, s, look.t(12))
    legend = [(MATCH_RGB, "cross", "features found in both photos (matches the geometry agrees with)"),
              ((255, 255, 255), "cross", "the clicked point")]
    if pixel is not None and g.F is not None and g.H is None:
        _line(b, g.F @ np.array([pixel[0], pixel[1], 1.0]), sup_rgb.shape[:2], t, render.LINE_RGB, 3)
        legend.append((render.LINE_RGB, "line", "where the point can lie in the support: its epipolar line"))
    elif pixel is not None and g.H is not None:
        q = g.H @ np.array([pixel[0], pixel[1], 1.0])
        render.draw_cross(b, _sc(q[:2] / q[2], t), render.LINE_RGB, size=14, thickness=3)
        legend.append((render.LINE_RGB, "cross", "where the homography puts it in the support"))
    unc = f" · lines sure to ±{g.uncertainty_px:.1f} px" if np.isfinite(g.uncertainty_px) else ""
    a, bar = _labelled(a, f"{ref_name} (reference)", "click a point", look)
    b, _ = _labelled(b, f"{sup_name} (support)", f"{len(g.inliers_ref)} matches · geometry: {g.source}{unc}", look)
    top = arrange(a, b, one_above(a.shape, b.shape, b.shape, look, _legend_h(look)))
    return Picture(render.stack([top, _legend(legend, top.shape[1], look)]), (0.0, float(bar), s))


def _strip_polygon(st, s_id: int) -> np.ndarray:
    """The reference strip s_id as a quadrilateral (near-left, far-left, far-right, near-right),
    with the pipeline's strip frame (patches.ref_frames)."""
    d, n = ref_frames(st)
    t_a, t_b = st.t0[s_id], st.t0[s_id] + st.n_along[s_id]
    half = np.tan(0.5 * st.dtheta)
    return np.array([st.epipole + t * d[s_id] + side * half * t * n[s_id]
                     for t, side in ((t_a, -1), (t_b, -1), (t_b, 1), (t_a, 1))])


def strips_picture(ref_rgb: np.ndarray, sup_rgb: np.ndarray, pair, pixel: np.ndarray | None, ev,
                   ref_name: str, sup_name: str, look: Look = PLAIN) -> Picture:
    """Step 3: the reference's first fan of strips (yellow boundaries, from the epipole), the clicked
    point's strip (filled) and patch (white); in the support, the corresponding strip boundaries
    and the point's strip between its two lines (blue)."""
    a, s = _photo_h(ref_rgb, HEIGHT)
    b, t = _photo_h(sup_rgb, HEIGHT)
    if pair is None or pair.kind != "epipolar" or pair.strips is None:
        msg = ("This support is aligned by one homography (a shot from about the same spot, or a flat scene): "
               "it has no strips. Choose an epipolar support in the tour panel.")
        return Picture(render.paragraph(msg, 2 * WIDTH, look.t(20)))
    st, sg = pair.strips, pair.segments
    fan0 = np.nonzero(st.fan == 0)[0]
    th = st.theta_c[fan0] - 0.5 * st.dtheta
    dirs = np.stack([np.cos(th), np.sin(th)], axis=1)
    t0, t1 = st.t0[fan0], st.t0[fan0] + st.n_along[fan0]
    strip_id = None
    if ev is not None and ev.patch is not None:
        strip_id = int(pair.patches.strip[ev.patch.patch])
    if strip_id is not None:                        # the point's strip, filled, under the lines
        poly = np.round(_sc(_strip_polygon(st, strip_id), s)).astype(np.int32)
        over = a.copy()
        cv2.fillPoly(over, [poly], render.STRIP_RGB, cv2.LINE_AA)
        a = np.ascontiguousarray((0.55 * a + 0.45 * over).astype(np.uint8))
    for k in range(len(fan0)):
        seg = np.stack([st.epipole + t0[k] * dirs[k], st.epipole + t1[k] * dirs[k]])
        render.draw_polyline(a, _sc(seg, s), render.LINE_RGB, 1, closed=False)
    for ln in sg.bound_a[np.isin(sg.strip, fan0)]:
        _line(b, ln, sup_rgb.shape[:2], t, render.LINE_RGB, 1)
    if strip_id is not None:
        render.draw_polyline(a, _sc(_strip_polygon(st, strip_id), s), render.STRIP_RGB, 2, outline=True)
        render.draw_polyline(a, _sc(ev.patch.ref_quad, s), render.REF_RGB, 3, outline=True)
        for g in np.nonzero(sg.strip == strip_id)[0]:
            _line(b, sg.bound_a[g], sup_rgb.shape[:2], t, render.STRIP_RGB, 3)
            _line(b, sg.bound_b[g], sup_rgb.shape[:2], t, render.STRIP_RGB, 3)
    _cross(a, pixel, s, look.t(8), ring=strip_id is None)
    fans = f"the first of {st.n_fans} fans" if st.n_fans > 1 else "its one fan"
    a, bar = _labelled(a, f"{ref_name} (reference)", f"{len(fan0)} strips in {fans}", look)
    b, _ = _labelled(b, f"{sup_name} (support)", "the same strips, between corresponding lines", look)
    top = arrange(a, b, one_above(a.shape, b.shape, b.shape, look, _legend_h(look)))
    legend = [(render.LINE_RGB, "line", "strip boundaries (epipolar lines)"),
              (render.STRIP_RGB, "line", "the clicked point's strip"), (render.REF_RGB, "box", "its patch")]
    if strip_id is None:
        legend.append(((150, 150, 150), "box", "click a point to see its strip" if pixel is None else "finding "
                                                                                                    "its strip…"))
    return Picture(render.stack([top, _legend(legend, top.shape[1], look)]), (0.0, float(bar), s))


def _along(ev) -> np.ndarray:
    """Each candidate's position along the strip (px from the first candidate, working
    resolution), measured along the pixel's epipolar line."""
    c = ev.patch.cand_quads.mean(axis=1).astype(np.float64)
    a, b = ev.line[0], ev.line[1]
    d = np.array([b, -a]) / max(np.hypot(a, b), 1e-12)
    pos = c @ d
    return pos - pos.min()


def candidates_picture(snap, report, ev, sup_name: str, width: int = WIDTH, look: Look = PLAIN) -> Picture:
    """Step 4: the support with every candidate of the point's patch (coloured by how unlike it is,
    by HOG: blue alike, red unlike), the best HOG (green) and best colour (orange); beside it the
    similarity of each candidate along the strip; below, the reference patch beside the best
    candidates, enlarged (compose.crops)."""
    sup_rgb = snap.photo_set.photos[ev.sup].rgb
    b, t = _photo(sup_rgb, width)
    p = ev.patch
    if ev.line is not None:
        _line(b, ev.line, sup_rgb.shape[:2], t, render.LINE_RGB, 1)
    if p is None or len(p.cand_quads) == 0:
        b, _ = _labelled(b, f"{sup_name} (support)", "no candidate: the point is out of this support's view", look)
        return Picture(b)
    sims = np.nan_to_num(p.sim_hog)
    quads = np.round(_sc(p.cand_quads, t)).astype(np.int32)
    bins = np.clip((1.0 - sims) * 12, 0, 11).astype(int)
    for k in sorted(set(bins.tolist()), reverse=True):      # one call per colour; the most alike on top
        cv2.polylines(b, list(quads[bins == k]), True, render.heat_colour((k + 0.5) / 12), 1, cv2.LINE_AA)
    render.draw_polyline(b, _sc(p.cand_quads[p.best_color], t), render.COLOR_RGB, 3, outline=True)
    render.draw_polyline(b, _sc(p.cand_quads[p.best_hog], t), render.HOG_RGB, 3, outline=True)
    b, _ = _labelled(b, f"{sup_name} (support)", f"{len(p.cand_quads)} candidates along the strip", look)
    crops_h = 2 * (look.t(17) + 4) + min(240, max(170, b.shape[1] // 5))
    under = one_above(b.shape, b.shape, (round(0.75 * b.shape[0]), b.shape[1]), look, _legend_h(look) + crops_h)
    chart_h = round(0.75 * b.shape[0]) if under else b.shape[0]
    if ev.kind == "epipolar" and ev.line is not None:
        x = _along(ev)
        o = np.argsort(x)
        right = chart([(x[o], p.sim_hog[o], render.HOG_RGB, "HOG (shape)"),
                       (x[o], p.sim_color[o], render.COLOR_RGB, "colour")], width, chart_h,
                      "position of the candidate along the strip (px)", "similarity to the reference patch",
                      marks=[(x[p.best_hog], float(p.sim_hog[p.best_hog]), render.HOG_RGB,
                              f"best HOG {p.sim_hog[p.best_hog]:.2f}"),
                             (x[p.best_color], float(p.sim_color[p.best_color]), render.COLOR_RGB,
                              f"best colour {p.sim_color[p.best_color]:.2f}")], size=look.t(16))
    else:
        right = render.paragraph("A homography pair: the patch is compared with the patches around where the "
                                 "homography puts it, not along a strip.", width, look.t(18))
    top = arrange(b, right, under)
    crops = compose.crops(snap, report, ev, top.shape[1], look.t(17))
    legend = [(render.heat_colour(0.1), "box", "a candidate like the patch"),
              (render.heat_colour(0.9), "box", "unlike"), (render.HOG_RGB, "box", "best by HOG (shape)"),
              (render.COLOR_RGB, "box", "best by colour"), (render.LINE_RGB, "line", "the point's epipolar line")]
    if ev.depth_point is not None and np.all(np.isfinite(ev.depth_point)):
        legend.append((render.STRIP_RGB, "box", "shared depth: the supports' common depth (ours)"))
    return Picture(render.stack([top, _legend(legend, top.shape[1], look), crops]))


def support_map_picture(ref_rgb: np.ndarray, sup_rgb: np.ndarray, match_prob: np.ndarray, pixel, value,
                        ref_name: str, sup_name: str, width: int = WIDTH, look: Look = PLAIN) -> Picture:
    """Step 5: P(x|I_s) of one support over the reference, drawn as 1 − P (blue: a match, red:
    none) as in the Supports tab, with its key; the support photo beside it."""
    over = render.overlay(ref_rgb, 1.0 - match_prob, 1.0, render.Layers(photo=True, heat=True, mask=False,
                                                                          gt=False, opacity=0.6))
    a, s = _photo_h(over, HEIGHT, MIN_WIDTH)
    _cross(a, pixel, s, look.t(12))
    sub = f"P(x|I_s) at the point: {value:.2f}" if value is not None and np.isfinite(value) else "click a point"
    a, bar = _labelled(a, f"{ref_name}: what {sup_name} says", sub, look)
    b, _ = _photo_h(sup_rgb, HEIGHT // 2, MIN_WIDTH // 2)
    b, _ = _labelled(b, f"{sup_name} (the support)", "", look)
    key_h = 3 * look.t(17) + 40
    top = arrange(a, b, one_above(a.shape, b.shape, b.shape, look, key_h))
    key = render.colour_key(a.shape[1], "mismatch", (1.0 - float(np.nanmax(match_prob)),
                                                     1.0 - float(np.nanmin(match_prob))), size=look.t(17))
    return Picture(render.stack([top, key]), (0.0, float(bar), s))


GRID_GAP = 6


def _grid_shape(n: int, columns: int, tile: float, tile_aspect: float, bar: float) -> tuple[float, float]:
    """(h, w) of a grid of n tiles `tile` px wide (pictures h / w = tile_aspect, under a caption
    bar), `columns` wide."""
    rows = int(np.ceil(n / columns))
    return rows * (tile * tile_aspect + bar) + (rows - 1) * GRID_GAP, columns * tile + (columns - 1) * GRID_GAP


def sweep_grid(maps, names: list[str], subs: list[str], threshold: float, tile: int, columns: int,
               size: int) -> np.ndarray:
    """The sweep's maps (the Sweep tab's, the paper's Fig. 5) as captioned tiles, `tile` px wide,
    in `columns` columns: P_dynamic in the main view's colours, the mask outlined."""
    tiles = []
    for m, name, sub in zip(maps, names, subs):
        img = render.overlay(np.zeros((*m.shape, 3), np.uint8), m, threshold,
                             render.Layers(photo=False, heat=True, mask=True, gt=False))
        tiles.append(render.label(np.ascontiguousarray(render.fit(img, tile)), name, sub, size=size))
    return render.mosaic(tiles, columns, gap=GRID_GAP)


def fusion_picture(main_img: np.ndarray, sweep, ref_name: str, n_sup: int, stems: list[str],
                   dyn: np.ndarray | None = None, threshold: float = 0.5, outlines=(True, False),
                   look: Look = PLAIN) -> Picture:
    """Step 6: the fused map (the main view's picture, with the main view's key drawn at its
    width: dyn's range, the threshold, the outlines) and the sweep over the supports (sweep: the
    Sweep tab's (SweepView, Jaccards or None), the paper's Fig. 5) as a grid beside it or under
    it, in as many columns as show it largest on the look's canvas."""
    a, s = _photo_h(main_img, HEIGHT, MIN_WIDTH)
    a, bar = _labelled(a, f"{ref_name}: all {n_sup} supports fused (Eq. 3)", "click a point", look)
    if dyn is not None:
        key = render.colour_key(a.shape[1], "dynamic", (float(dyn.min()), float(dyn.max())), threshold,
                                outlines=outlines, size=look.t(17))
        a = render.stack([a, key], gap=4)
    view, scores = sweep if sweep is not None else (None, None)
    if view is None or not view.maps:
        return Picture(side_by_side(a, render.message("the sweep: computing…", 360, look.t(18))), (0.0, float(bar), s))
    n = len(view.maps)
    size = look.t(15)
    cap = 2 * (size + 7)                      # a caption may take two lines
    mh, mw = view.maps[0].shape
    best = None
    for columns in range(1, min(n, 6) + 1):
        for under in (False, True):
            t = (a.shape[1] - (columns - 1) * GRID_GAP) / columns if under else \
                (a.shape[0] - (np.ceil(n / columns) - 1) * GRID_GAP) / np.ceil(n / columns) / (mh / mw) - cap * mw / mh
            if t < 60:
                continue
            shape = _grid_shape(n, columns, t, mh / mw, cap)
            if look.aspect is None:
                score = -1.0 if under else -abs(columns - 2)        # beside, in two columns (the Sweep tab's)
            else:
                total = (a.shape[0] + 12 + shape[0], max(a.shape[1], shape[1])) if under else \
                    (max(a.shape[0], shape[0]), a.shape[1] + 12 + shape[1])
                score = _shows(total[1], total[0], look.aspect) * np.sqrt(t)   # the map and the tiles large
            if best is None or score > best[0]:
                best = (score, columns, int(t), under)
    if best is None:
        best = (0, 2, 120, False)
    _, columns, tile, under = best
    names = [f"{k}: +{stems[j]}" for k, j in enumerate(view.supports, start=1)]
    subs = [f"Jaccard {v:.2f}" for v in scores] if scores else [f"{(m > threshold).mean():.0%} marked" for m in view.maps]
    b = sweep_grid(view.maps, names, subs, threshold, tile, columns, size)
    return Picture(arrange(a, b, under), (0.0, float(bar), s))


def result_picture(ref_rgb: np.ndarray, dyn: np.ndarray | None, gt: np.ndarray | None, threshold: float,
                   pixel, sc, ref_name: str, width: int = WIDTH, look: Look = PLAIN) -> Picture:
    """Step 7: the map with the mask (red) and the ground truth (green) outlined, and the Jaccard
    for every threshold (model.score's curve) beside it."""
    img = render.overlay(ref_rgb, dyn, threshold, render.Layers(photo=True, heat=True, mask=True, gt=True,
                                                                opacity=0.5), gt)
    a, s = _photo_h(img, HEIGHT, MIN_WIDTH)
    _cross(a, pixel, s, look.t(12))
    sub = (f"Jaccard {sc.at_threshold:.2f} at threshold {threshold:.2f}" if sc is not None
           else ("no ground truth for this photo" if gt is None else "computing…"))
    a, bar = _labelled(a, f"{ref_name}: marked moving vs. what moved", sub, look)
    key = render.colour_key(a.shape[1], "dynamic", None if dyn is None else (float(dyn.min()), float(dyn.max())),
                            threshold, outlines=(True, gt is not None), size=look.t(17))
    left = render.stack([a, key], gap=4)
    if sc is not None:
        under = one_above(left.shape, (a.shape[0], width), (round(0.6 * a.shape[0]), left.shape[1]), look)
        cw, ch = (left.shape[1], round(0.6 * a.shape[0])) if under else (width, a.shape[0])
        right = chart([(THRESHOLDS, sc.curve, (31, 95, 191), "Jaccard")], cw, ch,
                      "threshold", "Jaccard (overlap with the ground truth)",
                      marks=[(threshold, sc.at_threshold, (201, 42, 42), f"now {sc.at_threshold:.2f}"),
                             (sc.best_threshold, sc.best, (31, 95, 191), f"best {sc.best:.2f}")],
                      x_range=(0.0, 1.0), size=look.t(16))
    else:
        under = False
        right = render.paragraph("This photo has no ground truth: the map is all there is to judge. Sets with "
                                 "ground truth (gt/ beside the photos) get the Jaccard here.", width // 2, look.t(18))
    return Picture(arrange(left, right, under), (0.0, float(bar), s))


def busy_picture(text: str, width: int = 2 * WIDTH, look: Look = PLAIN) -> Picture:
    return Picture(render.paragraph(text, width, look.t(22)))


def default_pixel(dyn: np.ndarray, gt: np.ndarray | None = None) -> np.ndarray:
    """A point worth explaining when none is clicked: where P_dynamic, averaged over a window (so
    that one stray pixel does not win), is highest, away from the photo's border (where fewer
    supports see the scene) and inside the ground truth's moving region when there is one."""
    h, w = dyn.shape
    k = max(3, (min(h, w) // 24) | 1)
    sm = cv2.blur(dyn.astype(np.float32), (k, k))
    m = max(k, min(h, w) // 12)
    inner = np.zeros((h, w), bool)
    inner[m:h - m, m:w - m] = True
    if gt is not None and (gt & inner).any():
        inner &= gt
    sm = np.where(inner, sm, -1.0)
    v, u = np.unravel_index(int(np.argmax(sm)), sm.shape)
    return np.array([float(u), float(v)])
