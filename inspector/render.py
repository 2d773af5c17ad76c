"""Pictures for the inspector: pure numpy/OpenCV, no viser.

Every function takes and returns (h, w, 3) uint8 RGB unless stated otherwise. The numbers drawn
come from the pipeline's results; nothing here computes evidence.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

MASK_RGB = (255, 40, 40)
GT_RGB = (40, 255, 80)
HOG_RGB = (60, 220, 60)
COLOR_RGB = (255, 150, 20)
LINE_RGB = (255, 235, 0)
STRIP_RGB = (0, 220, 255)        # the bounded strip and the shared depth (sweep)
FONT = cv2.FONT_HERSHEY_SIMPLEX


def heat(prob: np.ndarray) -> np.ndarray:
    """(h, w) float in [0, 1] -> (h, w, 3) uint8 RGB, OpenCV's 'turbo' colour map."""
    u8 = (np.clip(np.nan_to_num(prob), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    return cv2.applyColorMap(u8, cv2.COLORMAP_TURBO)[..., ::-1]


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
    return cv2.resize(rgb, (width, max(1, round(h * width / w))), interpolation=cv2.INTER_AREA)


def label(rgb: np.ndarray, text: str, sub: str = "", dim: bool = False) -> np.ndarray:
    """A caption bar above the picture; `dim` greys the picture (a support switched off)."""
    img = rgb
    if dim:
        g = img.mean(axis=2, keepdims=True)
        img = (0.35 * g + 0.25 * 255).astype(np.uint8).repeat(3, axis=2)
    bar = np.full((18, img.shape[1], 3), 255, np.uint8)
    cv2.putText(bar, text, (3, 13), FONT, 0.42, (0, 0, 0) if not dim else (130, 130, 130), 1, cv2.LINE_AA)
    if sub:
        (tw, _), _ = cv2.getTextSize(sub, FONT, 0.38, 1)
        cv2.putText(bar, sub, (img.shape[1] - tw - 3, 13), FONT, 0.38, (90, 90, 90), 1, cv2.LINE_AA)
    return np.vstack([bar, img])


def mosaic(tiles: list[np.ndarray], columns: int, gap: int = 4) -> np.ndarray:
    """Tiles of equal width in a grid on white, row heights = tallest tile of the row."""
    if not tiles:
        return np.full((24, 24, 3), 255, np.uint8)
    w = max(t.shape[1] for t in tiles)
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


def bar_chart(names: list[str], values: list[float], aggregate: float, threshold: float,
              width: int = 380) -> np.ndarray:
    """Horizontal bars of P(x|I_s) per support (values in [0, 1], NaN = no data) and the aggregate
    P_dynamic; a dashed line marks 0.5 (a support with no opinion)."""
    rows = names + ["P_dynamic"]
    vals = list(values) + [aggregate]
    rh, left, right = 20, 92, 44
    h = rh * len(rows) + 22
    img = np.full((h, width, 3), 255, np.uint8)
    span = width - left - right
    for k, (n, v) in enumerate(zip(rows, vals)):
        y = 4 + k * rh
        agg = k == len(rows) - 1
        cv2.putText(img, n[:13], (4, y + 14), FONT, 0.42, (0, 0, 0), 1 if not agg else 2, cv2.LINE_AA)
        if v is None or not np.isfinite(v):
            cv2.putText(img, "no data", (left + 4, y + 14), FONT, 0.4, (140, 140, 140), 1, cv2.LINE_AA)
            continue
        if agg:
            colour = MASK_RGB if v > threshold else (90, 90, 90)
        else:       # a support that finds a match says "static": blue; no match: orange
            colour = (60, 110, 220) if v >= 0.5 else COLOR_RGB
        cv2.rectangle(img, (left, y + 3), (left + int(round(v * span)), y + rh - 3), colour, -1)
        cv2.putText(img, f"{v:.2f}", (left + span + 4, y + 14), FONT, 0.42, (0, 0, 0), 1, cv2.LINE_AA)
    x5 = left + span // 2
    for y in range(2, h - 20, 6):
        cv2.line(img, (x5, y), (x5, y + 3), (0, 0, 0), 1)
    yb = h - 14
    cv2.putText(img, "0", (left - 3, yb + 10), FONT, 0.38, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(img, "0.5", (x5 - 9, yb + 10), FONT, 0.38, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(img, "1", (left + span - 3, yb + 10), FONT, 0.38, (0, 0, 0), 1, cv2.LINE_AA)
    return img


def draw_polyline(rgb: np.ndarray, pts: np.ndarray, colour, thickness: int = 1, closed: bool = True) -> None:
    """Draw (N, 2) float points (pixel centres) in place, with 4-bit sub-pixel precision."""
    p = np.round(np.asarray(pts, np.float64) * 16).astype(np.int32).reshape(-1, 1, 2)
    cv2.polylines(rgb, [p], closed, colour, thickness, cv2.LINE_AA, shift=4)


def draw_cross(rgb: np.ndarray, xy, colour, size: int = 7) -> None:
    x, y = int(round(xy[0])), int(round(xy[1]))
    cv2.line(rgb, (x - size, y), (x + size, y), (0, 0, 0), 3, cv2.LINE_AA)
    cv2.line(rgb, (x, y - size), (x, y + size), (0, 0, 0), 3, cv2.LINE_AA)
    cv2.line(rgb, (x - size, y), (x + size, y), colour, 1, cv2.LINE_AA)
    cv2.line(rgb, (x, y - size), (x, y + size), colour, 1, cv2.LINE_AA)
