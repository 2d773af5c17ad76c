"""Pictures for the inspector: pure numpy/OpenCV/Pillow, no viser.

Every function takes and returns (h, w, 3) uint8 RGB unless stated otherwise. The numbers drawn
come from the pipeline's results; nothing here computes evidence.

One colour language everywhere: OpenCV's 'turbo' map, blue = static / a match was found, red =
moving / no match. The main map shows P_dynamic, the per-support tiles 1 - P(x|I_s), and the
votes of the fusion chart are blue when they say "static" and red when they say "moving".
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np
from PIL import Image, ImageDraw, ImageFont

MASK_RGB = (255, 40, 40)
GT_RGB = (40, 255, 80)
HOG_RGB = (60, 220, 60)
COLOR_RGB = (255, 150, 20)
LINE_RGB = (255, 235, 0)
STRIP_RGB = (0, 220, 255)        # the bounded strip and the shared depth (sweep)
REF_RGB = (255, 255, 255)        # the reference patch
INK = (20, 24, 28)               # text on white: 16:1
GREY_INK = (73, 80, 87)          # secondary text on white: 8:1
FONT = cv2.FONT_HERSHEY_SIMPLEX
_FONT_FILES = {False: ("DejaVuSans.ttf", "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
                       "LiberationSans-Regular.ttf"),
               True: ("DejaVuSans-Bold.ttf", "/usr/share/fonts/truetype/dejavu/DejaVuSans-Bold.ttf",
                      "LiberationSans-Bold.ttf")}


@lru_cache(maxsize=64)
def font(size: int, bold: bool = False) -> ImageFont.ImageFont:
    """A sans-serif TrueType font of `size` px (DejaVu; Pillow's own font where it is missing)."""
    for name in _FONT_FILES[bold]:
        try:
            return ImageFont.truetype(name, size)
        except OSError:
            continue
    return ImageFont.load_default(size=size)


def heat(prob: np.ndarray) -> np.ndarray:
    """(h, w) float in [0, 1] -> (h, w, 3) uint8 RGB, OpenCV's 'turbo' colour map (0 blue, 1 red)."""
    u8 = (np.clip(np.nan_to_num(prob), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    return cv2.applyColorMap(u8, cv2.COLORMAP_TURBO)[..., ::-1]


def heat_colour(value: float) -> tuple[int, int, int]:
    """The 'turbo' colour of one value in [0, 1], as the maps draw it."""
    return tuple(int(c) for c in heat(np.array([[value]], np.float32))[0, 0])


STATIC_RGB = heat_colour(0.12)   # a vote for "static" / "a match"
MOVING_RGB = heat_colour(0.88)   # a vote for "moving" / "no match"


@dataclass(frozen=True)
class Layers:
    """What the main view shows. opacity: weight of the heat map over the photo, in [0, 1]."""

    photo: bool = True
    heat: bool = True
    mask: bool = True
    gt: bool = True
    opacity: float = 0.55


def contour(mask: np.ndarray, width: int = 2) -> np.ndarray:
    """(h, w) bool -> (h, w) bool outline of the mask's regions, about `width` px thick."""
    m = mask.astype(np.uint8)
    k = np.ones((2 * width + 1, 2 * width + 1), np.uint8)
    return (cv2.dilate(m, k) > 0) & ~(cv2.erode(m, k) > 0) if m.any() else np.zeros(mask.shape, bool)


def overlay(rgb: np.ndarray, dynamic_prob: np.ndarray | None, threshold: float, layers: Layers,
            gt: np.ndarray | None = None) -> np.ndarray:
    """The main view: the photo, the P_dynamic heat map blended at layers.opacity, the mask at
    `threshold` as a red outline with a light tint, the ground truth as a green outline.

    rgb: (h, w, 3) uint8; dynamic_prob: (h, w) float32 in [0, 1] or None (not computed yet);
    gt: (h, w) bool at the same size, or None.
    """
    base = rgb if layers.photo else np.full(rgb.shape, 40, np.uint8)
    out = base.copy()
    if dynamic_prob is not None:
        if layers.heat:
            a = float(np.clip(layers.opacity, 0.0, 1.0)) if layers.photo else 1.0
            out = cv2.addWeighted(base, 1.0 - a, heat(dynamic_prob), a, 0.0)
        if layers.mask:
            mask = dynamic_prob > threshold
            tint = cv2.addWeighted(out, 0.75, np.full_like(out, MASK_RGB), 0.25, 0.0)
            np.copyto(out, tint, where=mask[..., None])
            out[contour(mask)] = MASK_RGB
    if layers.gt and gt is not None:
        out[contour(gt, 1)] = GT_RGB
    return out


def fit(rgb: np.ndarray, width: int) -> np.ndarray:
    """Resize to the given width, keeping the aspect ratio."""
    h, w = rgb.shape[:2]
    if w == width:
        return rgb
    interp = cv2.INTER_AREA if width < w else cv2.INTER_LINEAR
    return cv2.resize(rgb, (width, max(1, round(h * width / w))), interpolation=interp)


# ----------------------------------------------------------------------------- text
def _canvas(w: int, h: int) -> tuple[Image.Image, ImageDraw.ImageDraw]:
    im = Image.new("RGB", (max(1, int(w)), max(1, int(h))), (255, 255, 255))
    return im, ImageDraw.Draw(im)


def text_width(s: str, size: int, bold: bool = False) -> int:
    return int(math.ceil(font(size, bold).getlength(s)))


def put_text(rgb: np.ndarray, xy, s: str, size: int = 14, colour=INK, bold: bool = False,
             anchor: str = "la", halo: bool = False) -> np.ndarray:
    """Text drawn onto a copy of an image (anti-aliased TrueType); halo: a dark outline so light
    text reads on a photo."""
    im = Image.fromarray(rgb)
    d = ImageDraw.Draw(im)
    kw = {"stroke_width": max(1, size // 8), "stroke_fill": (0, 0, 0)} if halo else {}
    d.text(xy, s, fill=tuple(colour), font=font(size, bold), anchor=anchor, **kw)
    return np.asarray(im)


def label(rgb: np.ndarray, text: str, sub: str = "", dim: bool = False, size: int = 13) -> np.ndarray:
    """A caption bar above the picture (`sub` right-aligned); `dim` greys the picture (a support
    switched off)."""
    img = rgb
    if dim:
        g = img.mean(axis=2, keepdims=True)
        img = (0.35 * g + 0.25 * 255).astype(np.uint8).repeat(3, axis=2)
    w = img.shape[1]
    two = bool(sub) and text_width(text, size, True) + text_width(sub, size - 1) + 12 > w
    bar, d = _canvas(w, (size + 7) * (2 if two else 1))
    d.text((3, 3), text, fill=INK if not dim else GREY_INK, font=font(size, True))
    if sub:
        if two:
            d.text((3, size + 8), sub, fill=GREY_INK, font=font(size - 1))
        else:
            d.text((w - 3, 3), sub, fill=GREY_INK, font=font(size - 1), anchor="ra")
    return np.vstack([np.asarray(bar), img])


def mosaic(tiles: list[np.ndarray], columns: int, gap: int = 4) -> np.ndarray:
    """Tiles of equal width in a grid on white, row heights = tallest tile of the row."""
    if not tiles:
        return np.full((24, 24, 3), 255, np.uint8)
    w = max(t.shape[1] for t in tiles)
    columns = max(1, min(columns, len(tiles)))
    rows = []
    for r in range(0, len(tiles), columns):
        row = tiles[r:r + columns]
        h = max(t.shape[0] for t in row)
        canvas = np.full((h, columns * w + (columns - 1) * gap, 3), 255, np.uint8)
        for k, t in enumerate(row):
            canvas[:t.shape[0], k * (w + gap):k * (w + gap) + t.shape[1]] = t
        rows.append(canvas)
    out = [rows[0]]
    for r in rows[1:]:
        out += [np.full((gap, r.shape[1], 3), 255, np.uint8), r]
    return np.vstack(out)


def stack(parts: list[np.ndarray], gap: int = 6) -> np.ndarray:
    """Pictures one above the other on white, left-aligned."""
    w = max(p.shape[1] for p in parts)
    out = []
    for k, p in enumerate(parts):
        if k:
            out.append(np.full((gap, w, 3), 255, np.uint8))
        row = np.full((p.shape[0], w, 3), 255, np.uint8)
        row[:, :p.shape[1]] = p
        out.append(row)
    return np.vstack(out)


def message(text: str, width: int = 360, size: int = 14) -> np.ndarray:
    """A white picture holding one line of text ("computing…" where a picture is not ready)."""
    im, d = _canvas(width, size + 16)
    d.text((6, 8), text, fill=GREY_INK, font=font(size))
    return np.asarray(im)


# ----------------------------------------------------------------------------- keys
def colour_key(width: int = 360, quantity: str = "dynamic", value_range: tuple[float, float] | None = None,
               threshold: float | None = None, outlines: tuple[bool, bool] = (False, False),
               size: int = 13) -> np.ndarray:
    """The key of a heat map: the 'turbo' gradient from 0 to 1, what its ends mean, the range
    this map spans (a bracket above the bar), the threshold (a black mark under it), and a legend
    of the mask (red) and ground-truth (green) outlines when `outlines` says so.

    quantity: "dynamic" (P_dynamic: 0 static ... 1 moving) or "mismatch" (1 - P(x|I_s): 0 a match
    ... 1 no match).
    """
    lo_txt, hi_txt, name = {"dynamic": ("0 static", "1 moving", "P_dynamic: how likely a point moved"),
                            "mismatch": ("0: a match", "1: no match", "1 − P(x|I_s): did the support find it?")
                            }[quantity]
    pad = 10
    bar_w = width - 2 * pad
    bar_h = 14
    y_title = 2
    y_range = y_title + size + 5
    top = y_range + (size + 8 if value_range is not None else 0)
    y_labels = top + bar_h + 4
    h = y_labels + size + 6
    im, d = _canvas(width, h)
    d.text((pad, y_title), name, fill=INK, font=font(size, True))
    grad = heat(np.tile(np.linspace(0, 1, bar_w, dtype=np.float32), (bar_h, 1)))
    im.paste(Image.fromarray(grad), (pad, top))
    d.rectangle([pad, top, pad + bar_w - 1, top + bar_h - 1], outline=(90, 90, 90))
    x_of = lambda v: pad + round(float(np.clip(v, 0, 1)) * (bar_w - 1))
    if value_range is not None and np.all(np.isfinite(value_range)):
        lo, hi = value_range
        y = top - 4
        d.line([x_of(lo), y, x_of(hi), y], fill=INK, width=2)
        d.line([x_of(lo), y - 4, x_of(lo), y + 3], fill=INK, width=2)
        d.line([x_of(hi), y - 4, x_of(hi), y + 3], fill=INK, width=2)
        txt = f"this photo: {lo:.2f}–{hi:.2f}"
        tw = text_width(txt, size - 1)
        cx = int(np.clip((x_of(lo) + x_of(hi)) / 2 - tw / 2, pad, width - pad - tw))
        d.text((cx, y_range), txt, fill=INK, font=font(size - 1))
    d.text((pad, y_labels), lo_txt, fill=INK, font=font(size))
    d.text((width - pad, y_labels), hi_txt, fill=INK, font=font(size), anchor="ra")
    if threshold is not None:
        xt = x_of(threshold)
        d.polygon([(xt - 6, top + bar_h + 8), (xt + 6, top + bar_h + 8), (xt, top + bar_h)], fill=INK)
        t = f"threshold {threshold:.2f}"
        tw = text_width(t, size)
        lo_end, hi_start = pad + text_width(lo_txt, size) + 8, width - pad - text_width(hi_txt, size) - 8
        tx = int(np.clip(xt + 9 if xt + 9 + tw <= hi_start else xt - 9 - tw, lo_end, max(lo_end, hi_start - tw)))
        d.text((tx, y_labels), t, fill=INK, font=font(size))
    key = np.asarray(im)
    if any(outlines):
        items = [(MASK_RGB, "box", "marked moving (above the threshold)")] if outlines[0] else []
        items += [(GT_RGB, "box", "ground truth")] if outlines[1] else []
        key = np.vstack([key, legend(items, width, size)])
    return key


def paragraph(text: str, width: int, size: int = 14, bold: bool = False, colour=INK, pad: int = 6) -> np.ndarray:
    """Text wrapped at word boundaries to `width` px, on white."""
    f = font(size, bold)
    lines, cur = [], ""
    for word in text.split():
        t = f"{cur} {word}".strip()
        if f.getlength(t) <= width - 2 * pad or not cur:
            cur = t
        else:
            lines.append(cur)
            cur = word
    lines.append(cur)
    im, d = _canvas(width, len(lines) * (size + 5) + 2 * pad - 4)
    for k, line in enumerate(lines):
        d.text((pad, pad - 2 + k * (size + 5)), line, fill=colour, font=f)
    return np.asarray(im)


def legend(items: list[tuple[tuple[int, int, int], str, str]], width: int, size: int = 13) -> np.ndarray:
    """A wrapped row of legend entries (colour, kind, text); kind: "line", "box", "cross"."""
    im, d = _canvas(width, 1000)
    x, y, pad = 6, 4, 6
    for colour, kind, txt in items:
        w = 24 + text_width(txt, size) + 14
        if x + w > width - pad and x > pad:
            x, y = pad, y + size + 8
        cy = y + size // 2 + 1
        dark = (40, 40, 40)
        if kind == "line":
            d.line([x, cy, x + 18, cy], fill=dark, width=5)
            d.line([x, cy, x + 18, cy], fill=colour, width=3)
        elif kind == "box":
            d.rectangle([x + 1, cy - 6, x + 17, cy + 6], outline=dark, width=4)
            d.rectangle([x + 2, cy - 5, x + 16, cy + 5], outline=colour, width=2)
        else:
            d.line([x + 2, cy, x + 16, cy], fill=dark, width=5)
            d.line([x + 9, cy - 7, x + 9, cy + 7], fill=dark, width=5)
            d.line([x + 2, cy, x + 16, cy], fill=colour, width=3)
            d.line([x + 9, cy - 7, x + 9, cy + 7], fill=colour, width=3)
        d.text((x + 24, y), txt, fill=INK, font=font(size))
        x += w
    return np.asarray(im)[:y + size + 8]


# ----------------------------------------------------------------------------- charts
@dataclass(frozen=True)
class VoteRow:
    """One row of the fusion chart: a name, its vote (log-odds for "moving"; NaN: none) and the
    running total after it."""

    name: str
    vote: float
    total: float
    note: str = ""
    neutral: bool = False        # a step that is not a vote (the mean): grey


def fusion_chart(rows: list[VoteRow], threshold_at: float, result: float, width: int = 360, size: int = 13,
                 result_name: str = "P_dynamic") -> np.ndarray:
    """The fusion as a waterfall: each support's vote moves the running total left (blue: says
    "static", it found a match) or right (red: says "moving", no match). The dashed line is where
    the total reaches the threshold; the last row is the total and the P_dynamic it gives.

    threshold_at: the total at which P_dynamic equals the threshold; result: P_dynamic."""
    left, right = 96, 52
    span = width - left - right
    vals = [0.0, threshold_at] + [r.total for r in rows] + [r.total - r.vote for r in rows if np.isfinite(r.vote)]
    lim = max(2.0, max(abs(v) for v in vals if np.isfinite(v)) * 1.08)
    x_of = lambda v: left + (float(np.clip(v, -lim, lim)) + lim) / (2 * lim) * span
    rh = size + 9
    top = size + 10
    n = len(rows) + 1
    h = top + rh * n + 2 * size + 16
    im, d = _canvas(width, h)
    d.text((left + span / 2, 2), "← static          moving →", fill=INK, font=font(size, True), anchor="ma")
    y0, y1 = top - 2, top + rh * n
    d.line([x_of(0), y0, x_of(0), y1], fill=(150, 150, 150), width=1)
    xt = x_of(threshold_at)
    for y in range(y0, y1, 6):
        d.line([xt, y, xt, min(y + 3, y1)], fill=INK, width=1)
    for k, r in enumerate(rows):
        y = top + k * rh
        d.text((4, y + 2), r.name[:12], fill=INK, font=font(size))
        if not np.isfinite(r.vote):
            d.text((left + 4, y + 2), r.note or "no vote", fill=GREY_INK, font=font(size - 1))
            continue
        a, b = x_of(r.total - r.vote), x_of(r.total)
        colour = (150, 150, 150) if r.neutral else MOVING_RGB if r.vote > 0 else STATIC_RGB
        d.rectangle([min(a, b), y + 3, max(max(a, b), min(a, b) + 1), y + rh - 4], fill=colour)
        if k + 1 < len(rows):             # the running total carries over to the next row
            d.line([b, y + rh - 4, b, y + rh + 3], fill=(110, 110, 110), width=1)
        d.text((width - 4, y + 2), f"{r.vote:+.2f}", fill=INK, font=font(size), anchor="ra")
    y = top + len(rows) * rh
    total = rows[-1].total if rows else 0.0
    d.text((4, y + 2), "total", fill=INK, font=font(size, True))
    d.rectangle([min(x_of(0), x_of(total)), y + 3, max(x_of(0), x_of(total)) + 1, y + rh - 4],
                fill=heat_colour(result), outline=INK)
    d.text((width - 4, y + 2), f"{total:+.2f}", fill=INK, font=font(size, True), anchor="ra")
    y = y1 + 4
    d.text((xt, y), "threshold", fill=INK, font=font(size - 1), anchor="ma")
    d.text((4, y + size + 2), f"→ {result_name} {result:.2f}", fill=INK, font=font(size, True))
    return np.asarray(im)


def value_bars(names: list[str], values: list[float], result: float, threshold: float, width: int = 360,
               size: int = 13, result_name: str = "P_dynamic") -> np.ndarray:
    """Horizontal bars of values in [0, 1] coloured like the maps (NaN: no data), and the result;
    a dashed line at the threshold (used for the peer baseline, whose fusion is a median)."""
    left, right = 96, 46
    span = width - left - right
    rh = size + 9
    rows = list(zip(names, values)) + [(result_name, result)]
    h = rh * len(rows) + size + 14
    im, d = _canvas(width, h)
    for k, (n, v) in enumerate(rows):
        y = 2 + k * rh
        last = k == len(rows) - 1
        d.text((4, y + 2), n[:12], fill=INK, font=font(size, last))
        if v is None or not np.isfinite(v):
            d.text((left + 4, y + 2), "no data", fill=GREY_INK, font=font(size - 1))
            continue
        d.rectangle([left, y + 3, left + max(1, round(v * span)), y + rh - 4], fill=heat_colour(v),
                    outline=INK if last else None)
        d.text((width - 4, y + 2), f"{v:.2f}", fill=INK, font=font(size, last), anchor="ra")
    xt = left + threshold * span
    for y in range(0, rh * len(rows), 6):
        d.line([xt, y, xt, y + 3], fill=INK, width=1)
    y = rh * len(rows) + 2
    d.text((left, y), "0", fill=INK, font=font(size - 1), anchor="ma")
    d.text((xt, y), "threshold", fill=INK, font=font(size - 1), anchor="ma")
    d.text((left + span, y), "1", fill=INK, font=font(size - 1), anchor="ma")
    return np.asarray(im)


# ----------------------------------------------------------------------------- drawing on photos
def draw_polyline(rgb: np.ndarray, pts: np.ndarray, colour, thickness: int = 1, closed: bool = True,
                  outline: bool = False) -> None:
    """Draw (N, 2) float points (pixel centres) in place, with 4-bit sub-pixel precision;
    outline: a dark border first, so the line reads on any photo."""
    p = np.round(np.asarray(pts, np.float64) * 16).astype(np.int32).reshape(-1, 1, 2)
    if outline:
        cv2.polylines(rgb, [p], closed, (0, 0, 0), thickness + 2, cv2.LINE_AA, shift=4)
    cv2.polylines(rgb, [p], closed, colour, thickness, cv2.LINE_AA, shift=4)


def draw_cross(rgb: np.ndarray, xy, colour, size: int = 7, thickness: int = 1) -> None:
    x, y = int(round(xy[0])), int(round(xy[1]))
    for c, t in (((0, 0, 0), thickness + 2), (colour, thickness)):
        cv2.line(rgb, (x - size, y), (x + size, y), c, t, cv2.LINE_AA)
        cv2.line(rgb, (x, y - size), (x, y + size), c, t, cv2.LINE_AA)


def crop(rgb: np.ndarray, centre, side: float, out: int) -> tuple[np.ndarray, np.ndarray]:
    """A square of `side` working pixels around `centre`, scaled to out x out (grey outside the
    photo). Returns the crop and the 2x3 affine that maps photo pixels into it."""
    s = out / max(side, 1.0)
    cx, cy = float(centre[0]), float(centre[1])
    A = np.array([[s, 0, out / 2 - s * cx], [0, s, out / 2 - s * cy]], np.float64)
    img = cv2.warpAffine(rgb, A, (out, out), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                         borderValue=(128, 128, 128))
    return img, A


def apply_affine(A: np.ndarray, pts: np.ndarray) -> np.ndarray:
    p = np.asarray(pts, np.float64).reshape(-1, 2)
    return p @ A[:, :2].T + A[:, 2]
