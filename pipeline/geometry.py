"""Epipolar geometry: pure functions on fundamental matrices and points.

Convention everywhere: `x_support^T F x_reference = 0`, points as pixel coordinates with
(0, 0) at the centre of the top-left pixel (OpenCV's convention).
"""

from __future__ import annotations

import numpy as np


def to_homogeneous(pts: np.ndarray) -> np.ndarray:
    """(N, 2) -> (N, 3) float64 with a trailing 1."""
    pts = np.asarray(pts, dtype=np.float64)
    return np.concatenate([pts, np.ones((*pts.shape[:-1], 1))], axis=-1)


def epipoles(F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Homogeneous epipoles (e_ref, e_sup), unit norm: F e_ref = 0 and F^T e_sup = 0.

    e_ref is the image of the support camera's centre in the reference image.
    """
    _, _, vt = np.linalg.svd(F)
    e_ref = vt[-1]
    _, _, vt2 = np.linalg.svd(F.T)
    e_sup = vt2[-1]
    return e_ref / np.linalg.norm(e_ref), e_sup / np.linalg.norm(e_sup)


def epipolar_lines(F: np.ndarray, pts_ref: np.ndarray) -> np.ndarray:
    """Lines in the support image for reference points.

    pts_ref: (N, 2) float. Returns (N, 3) float64 lines (a, b, c) with a^2 + b^2 = 1, so that
    a*x + b*y + c is the signed distance of support pixel (x, y) to the line.
    """
    lines = to_homogeneous(pts_ref) @ F.T
    return lines / np.linalg.norm(lines[:, :2], axis=1, keepdims=True)


def symmetric_epipolar_distance(F: np.ndarray, pts_ref: np.ndarray, pts_sup: np.ndarray) -> np.ndarray:
    """(N,) float64: mean of the distances of each point to the other's epipolar line."""
    xr, xs = to_homogeneous(pts_ref), to_homogeneous(pts_sup)
    l_s = xr @ F.T          # lines in support
    l_r = xs @ F            # lines in reference
    num = np.abs(np.sum(xs * l_s, axis=1))
    return 0.5 * (num / np.linalg.norm(l_s[:, :2], axis=1) + num / np.linalg.norm(l_r[:, :2], axis=1))


def scale_matrix(scale: float) -> np.ndarray:
    """3x3 map from original to working pixel coordinates for a resize by `scale`.

    With pixel centres at integers, x_work = (x_orig + 0.5) * scale - 0.5.
    """
    return np.array([[scale, 0, 0.5 * scale - 0.5], [0, scale, 0.5 * scale - 0.5], [0, 0, 1.0]])


def fundamental_to_original(F_work: np.ndarray, scale_ref: float, scale_sup: float) -> np.ndarray:
    """F in working coordinates -> F in original-resolution coordinates (same convention), unit norm."""
    F = scale_matrix(scale_sup).T @ F_work @ scale_matrix(scale_ref)
    return F / np.linalg.norm(F)


def fundamental_from_cameras(P_ref: np.ndarray, P_sup: np.ndarray,
                             ref_parts: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """F with x_sup^T F x_ref = 0 from two 3x4 projection matrices (HZ eq. 9.1).

    ref_parts: camera_parts(P_ref), when the caller has them (they depend on the reference alone,
    and a set's checks ask for F of every pair: two SVDs a pair otherwise)."""
    C, P_pinv = camera_parts(P_ref) if ref_parts is None else ref_parts
    e_sup = P_sup @ C
    ex = np.array([[0, -e_sup[2], e_sup[1]], [e_sup[2], 0, -e_sup[0]], [-e_sup[1], e_sup[0], 0]])
    F = ex @ P_sup @ P_pinv
    return F / np.linalg.norm(F)


def camera_parts(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(the camera centre (4,), homogeneous, with P C = 0; the pseudo-inverse (4, 3)) of a 3x4 P."""
    _, _, vt = np.linalg.svd(P)
    return vt[-1], np.linalg.pinv(P)


def convex_hull_share(pts: np.ndarray, size: tuple[int, int]) -> float:
    """Area of the convex hull of (N, 2) points over the image area (h, w)."""
    import cv2

    if len(pts) < 3:
        return 0.0
    hull = cv2.convexHull(np.asarray(pts, dtype=np.float32))
    return float(cv2.contourArea(hull)) / float(size[0] * size[1])


def clip_line(l: np.ndarray, size: tuple[int, int]) -> np.ndarray | None:
    """Segment of line (a, b, c) inside an (h, w) image, (2, 2) float32, or None."""
    seg, ok = clip_lines(np.asarray(l, np.float64)[None], size)
    return seg[0] if ok[0] else None


def clip_lines(lines: np.ndarray, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Segments of lines (N, 3) inside an (h, w) image: ((N, 2, 2) float32, (N,) bool in view).

    Each line's crossings of the borders x = 0, x = w - 1, y = 0, y = h - 1 (in that order) that lie
    within the image; the segment joins the two farthest apart (the first such pair in row-major
    order). Fewer than two crossings: not in view (its segment is zeros)."""
    h, w = size
    lines = np.asarray(lines, np.float64).reshape(-1, 3)
    a, b, c = lines[:, 0:1], lines[:, 1:2], lines[:, 2:3]
    with np.errstate(divide="ignore", invalid="ignore"):
        xb = np.array([0.0, w - 1.0])[None]                                 # crossings of x = 0, w - 1
        yb = -(a * xb + c) / b
        ya = np.array([0.0, h - 1.0])[None]                                 # crossings of y = 0, h - 1
        xa = -(b * ya + c) / a
    pts = np.stack([np.concatenate([np.broadcast_to(xb, yb.shape), xa], 1),
                    np.concatenate([yb, np.broadcast_to(ya, xa.shape)], 1)], -1)          # (N, 4, 2)
    valid = np.concatenate([(np.abs(b) > 1e-12) & (yb >= 0) & (yb <= h - 1),
                            (np.abs(a) > 1e-12) & (xa >= 0) & (xa <= w - 1)], 1)       # (N, 4)
    # the farthest pair of valid crossings; invalid ones at -1 leave the first maximum in row-major
    # order where it is among the valid ones alone
    pts = np.where(valid[..., None], pts, 0.0)                          # (the others may be inf or NaN)
    d = np.linalg.norm(pts[:, :, None] - pts[:, None], axis=-1)
    d = np.where(valid[:, :, None] & valid[:, None], d, -1.0).reshape(len(lines), 16)
    k = np.argmax(d, axis=1)
    i, j = k // 4, k % 4
    rows = np.arange(len(lines))
    seg = np.stack([pts[rows, i], pts[rows, j]], 1).astype(np.float32)
    ok = valid.sum(axis=1) >= 2
    return np.where(ok[:, None, None], seg, 0.0).astype(np.float32), ok


def line_points(F: np.ndarray, size_ref: tuple[int, int], size_sup: tuple[int, int], grid: int = 12,
                per_line: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """Sample points on the epipolar lines of a grid of reference pixels, inside the support.

    Returns (x_ref (N, 2), y_sup (N, 2)) float64: y_sup lies on the line F x_ref, `per_line` points
    spread evenly over the part of the line inside the support image (lines that miss it give none).
    """
    h, w = size_ref
    gx, gy = np.meshgrid(np.linspace(0, w - 1, grid), np.linspace(0, h - 1, max(2, grid * h // max(w, 1))))
    x_ref = np.column_stack([gx.ravel(), gy.ravel()])
    t = (np.arange(per_line) + 0.5) / per_line
    seg, ok = clip_lines(epipolar_lines(F, x_ref), size_sup)
    seg = seg[ok]
    if not len(seg):
        return np.zeros((0, 2)), np.zeros((0, 2))
    ys = seg[:, None, 0] + t[None, :, None] * (seg[:, None, 1] - seg[:, None, 0])        # (N, per_line, 2)
    return np.repeat(x_ref[ok], per_line, axis=0), ys.reshape(-1, 2).astype(np.float64)


def line_spread(F: np.ndarray, F_alt: np.ndarray, size_ref: tuple[int, int], size_sup: tuple[int, int],
                q: float = 90.0) -> float:
    """How far the epipolar lines of F_alt lie from those of F over the whole image (not only at
    the matches): the q-th percentile, over points y on the lines F x of a grid of reference
    pixels x, of the distance of y to the line F_alt x. Working pixels; inf if no line is in view."""
    x_ref, y_sup = line_points(F, size_ref, size_sup)
    if len(x_ref) == 0:
        return float("inf")
    l_alt = epipolar_lines(F_alt, x_ref)
    d = np.abs(np.sum(l_alt[:, :2] * y_sup, axis=1) + l_alt[:, 2])
    return float(np.percentile(d, q))
