"""A plane sweep without cameras: one pencil of planes shared by a reference's two-view supports.

The depth cue (sweep.py) needs the set's cameras: planes in the reference camera's frame, mapped
into every support by plane-induced homographies. A photo the reconstruction did not register
(the set did not reconstruct, or not this photo) has only its pairs' fundamental matrices. They
are enough for a sweep all its supports share (a departure, `sweep.two_view`):

- **One pair.** Every homography of a plane between two photos with fundamental matrix F is
  H0 + e' v^T (HZ 13.2), for the support's epipole e' and some 3-vector v. The pencil
  H(s) = H0 + s e' (0, 0, 1) moves every reference pixel x along its epipolar line as s runs over
  the reals; with calibrated cameras s = k (rho - v0 . x), rho the inverse depth of x (HZ 13.2.1:
  a plane's homography is H_inf + t n^T / d): s is an inverse depth up to a scale and an offset
  that is affine in the pixel (two_view_pencil).
- **Several pairs.** So between two supports j and k, s_k = A s_j + a . x at every reference
  pixel (A a number, a a 3-vector, x homogeneous). A reference keypoint matched in both (a track)
  gives one such equation: the tracks fit A and a (align). And since a . x is linear in x, support
  k's warp for the anchor's s is again a homography, H0_k + e'_k a^T + A s e'_k (0, 0, 1): every
  support is warped for the same hypotheses, and the fusion, the one smooth depth and the
  calibration work as with cameras.

What it does not know is where infinity lies (no focal length, no metric depth): the range swept
is that of the tracks, widened by half on each side. A support that shares too few tracks with the
others (directly or through another support) is left out of the sweep (it still speaks through
its strips); a photo left with one support is swept only where that pair's lines are certain,
and its cue then counts at `sweep.lone_pencil_weight` (run._pencils, SetResult.sweep_log_odds:
nothing else checks its F). Shapes: pixels are working-resolution (x, y);
homographies map reference to support.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .geometry import epipoles, to_homogeneous

MIN_TRACKS = 8          # reference keypoints matched in both supports, to align one support to another
MAX_ALIGN_PX = 2.0      # the alignment's median residual, in support pixels, above which it is not trusted
MIN_SPAN_FRAC = 0.025   # the least the sweep moves a match either way along its line, x the working side (16 px at 640)


@dataclass(frozen=True)
class PencilSweep:
    """The shared sweep of one reference's two-view supports.

    base, step: support -> (3, 3) float64, working px: the support's homography for the anchor's
    pencil parameter rho is base + rho * step; rho: (D,) float64 the hypotheses swept, uniform
    (an inverse depth up to scale and a per-pixel offset); anchor: the support whose pencil is the
    axis; left_out: support -> why it is not swept.
    """

    base: dict[int, np.ndarray]
    step: dict[int, np.ndarray]
    rho: np.ndarray
    anchor: int
    left_out: dict[int, str]

    def homographies(self, j: int) -> np.ndarray:
        """(D, 3, 3) float64: support j's homography (reference -> support, working px) at every rho."""
        return self.base[j][None] + self.rho[:, None, None] * self.step[j][None]


def _similarity(pts: np.ndarray) -> np.ndarray:
    """3x3 map of points (N, 2) to their centroid at 0 and mean distance sqrt(2) (HZ 4.4.4)."""
    c = pts.mean(axis=0)
    d = np.mean(np.linalg.norm(pts - c, axis=1))
    s = np.sqrt(2.0) / max(d, 1e-9)
    return np.array([[s, 0, -s * c[0]], [0, s, -s * c[1]], [0, 0, 1.0]])


def two_view_pencil(F: np.ndarray, x_ref: np.ndarray, x_sup: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Homographies compatible with F without cameras: H(s) = H0 + s e' (0, 0, 1) (HZ 13.2).

    F: (3, 3) with x_sup^T F x_ref = 0 (working px); x_ref, x_sup: (N, 2) its inlier matches, N >= 3.
    H0 is the compatible homography closest to the matches (v by least squares, HZ 13.2.2: their
    mean plane). Returns H0 (3, 3), e' (3,) and each match's s (N,) solved from x_sup ~ H(s) x_ref,
    all in working px."""
    T_r, T_s = _similarity(x_ref), _similarity(x_sup)
    Fn = np.linalg.inv(T_s).T @ F @ np.linalg.inv(T_r)
    e = epipoles(Fn)[1]                                 # e'^T Fn = 0
    A = np.cross(e, Fn.T).T                             # [e']x Fn: a (degenerate) compatible homography
    xr = to_homogeneous(x_ref) @ T_r.T
    xs = to_homogeneous(x_sup) @ T_s.T
    xe = np.cross(xs, e)                                # (N, 3): x' x e'
    M = (xe[:, :, None] * xr[:, None, :]).reshape(-1, 3)      # (x' x e') x^T v = -x' x A x, three rows a match
    b = -np.cross(xs, xr @ A.T).reshape(-1)
    v = np.linalg.lstsq(M, b, rcond=None)[0]
    H0n = A + np.outer(e, v)
    s = -np.sum(xe * np.cross(xs, xr @ H0n.T), axis=1) / np.maximum(np.sum(xe * xe, axis=1), 1e-18)
    # back to working px: T_s^-1 (H0n + s e (0, 0, 1)) T_r, and (0, 0, 1) T_r = (0, 0, 1)
    Ts_inv = np.linalg.inv(T_s)
    return Ts_inv @ H0n @ T_r, Ts_inv @ e, s


def transfer(H0: np.ndarray, e: np.ndarray, x: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Support pixels (N, 2) of reference pixels x (N, 2) at pencil parameters s (N,)."""
    q = to_homogeneous(x) @ H0.T + s[:, None] * e[None]
    with np.errstate(divide="ignore", invalid="ignore"):
        return q[:, :2] / q[:, 2:]


def align(s_k: np.ndarray, rho: np.ndarray, x: np.ndarray, px_per_s: np.ndarray) -> tuple[np.ndarray, float]:
    """Fit s_k = A rho + a . (x, y, 1) over tracks (x (N, 2) reference px), trimmed least squares.

    px_per_s: (N,) how far support k's point moves per unit of s_k at each track, to read the
    residual in pixels. Returns (A, a0, a1, a2) (4,) and the median residual in support px."""
    X = np.column_stack([rho, x / 1000.0, np.ones(len(x))])         # pixels scaled: a conditioned system
    sv = np.linalg.svd(X, compute_uv=False)
    if sv[-1] < 1e-9 * sv[0]:       # tracks on one plane (rho follows the pixel): the scale A is free
        return np.full(4, np.nan), float("nan")
    keep = np.ones(len(x), bool)
    for _ in range(3):
        coef = np.linalg.lstsq(X[keep], s_k[keep], rcond=None)[0]
        res_px = np.abs(X @ coef - s_k) * px_per_s
        keep = res_px <= max(3.0 * np.median(res_px[keep]), 0.5)
        if keep.sum() < MIN_TRACKS:
            break
    coef = np.array([coef[0], coef[1] / 1000.0, coef[2] / 1000.0, coef[3]])
    return coef, float(np.median(res_px))


def shared_pencil(pairs: dict, size: tuple[int, int], max_planes: int, min_planes: int = 16,
                  grid_scale: float = 0.5, min_supports: int = 2, working_side: int | None = None
                  ) -> PencilSweep | None:
    """One sweep for a reference's two-view supports.

    pairs: support -> (F, inliers_ref (N, 2), inliers_sup (N, 2), track keys (N,): equal where two
    supports matched the same reference keypoint, e.g. support.position_keys(inliers_ref)), working
    px; size: the reference's (h, w). The anchor is the support with the most matches; the others join it in order of the tracks they share with those already in (each fitted to the
    already-aligned supports' tracks, align). The planes: uniform in the anchor's s over the range
    of every aligned support's tracks (2nd to 98th percentile, widened by half on each side), one
    sweep-grid pixel apart (grid_scale: the sweep grid / working size) at the 90th percentile of a
    grid of reference pixels in the support that moves most, min_planes to max_planes of them;
    at least MIN_SPAN_FRAC x working_side (the set's, PhotoSet.working_side; default the
    reference's longer side) either way of the middle. None when fewer than min_supports supports
    are aligned."""
    pencils = {}
    for j, (F, x_r, x_s, ids) in pairs.items():
        if F is None or len(x_r) < MIN_TRACKS:
            continue
        H0, e, s = two_view_pencil(F, np.asarray(x_r, float), np.asarray(x_s, float))
        # px per unit s at each match: the support point's speed along its line
        d = np.abs(transfer(H0, e, x_r, s + 1e-3) - transfer(H0, e, x_r, s)).max(axis=1) / 1e-3
        pencils[j] = (H0, e, s, np.asarray(x_r, float), np.asarray(ids), d)
    if not pencils:
        return None
    left_out = {j: "too few matches for a pencil" for j in pairs if j not in pencils}
    anchor = max(pencils, key=lambda j: len(pencils[j][2]))
    coef = {anchor: np.array([1.0, 0.0, 0.0, 0.0])}
    rho_at: dict[int, float] = {}            # track key -> the anchor's s there (mean over supports)
    n_at: dict[int, int] = {}

    def anchor_s(j):
        """(N,) the anchor's s at support j's matches (its own s = A rho + a . x, inverted)."""
        A, a0, a1, a2 = coef[j]
        x_r = pencils[j][3]
        return (pencils[j][2] - (a0 * x_r[:, 0] + a1 * x_r[:, 1] + a2)) / A

    def add_tracks(j):
        for k, v in zip(pencils[j][4].tolist(), anchor_s(j).tolist()):
            n = n_at.get(k, 0)
            rho_at[k] = (rho_at.get(k, 0.0) * n + v) / (n + 1)
            n_at[k] = n + 1
    add_tracks(anchor)
    waiting = [j for j in pencils if j != anchor]
    while waiting:
        shared = {j: [k for k in pencils[j][4].tolist() if k in rho_at] for j in waiting}
        j = max(waiting, key=lambda j: len(shared[j]))
        waiting.remove(j)
        if len(shared[j]) < MIN_TRACKS:
            left_out[j] = f"shares {len(shared[j])} tracks with the other supports (< {MIN_TRACKS})"
            continue
        H0, e, s, x_r, ids, d = pencils[j]
        pos = {k: n for n, k in enumerate(ids.tolist())}
        sel = np.array([pos[k] for k in shared[j]])
        c, res_px = align(s[sel], np.array([rho_at[k] for k in shared[j]]), x_r[sel], d[sel])
        if not np.isfinite(res_px):
            left_out[j] = "the tracks it shares lie on one plane (nothing fixes its pencil's scale)"
            continue
        if res_px > MAX_ALIGN_PX or abs(c[0]) < 1e-12:
            left_out[j] = f"its pencil does not align with the other supports' ({res_px:.1f} px)"
            continue
        coef[j] = c
        add_tracks(j)
    if len(coef) < min_supports:
        return None
    # the range, in the anchor's s, of every aligned support's matches
    rhos = np.concatenate([anchor_s(j) for j in coef])
    lo, hi = np.percentile(rhos, [2, 98])
    lo, hi = lo - 0.5 * (hi - lo), hi + 0.5 * (hi - lo)
    # at least MIN_SPAN_FRAC of the working side either way of the middle (matches on one plane have no
    # range of their own); a length that follows the working size, as the others do
    min_span_px = MIN_SPAN_FRAC * (working_side if working_side else max(size))
    half = min_span_px / max(float(np.median(pencils[anchor][5])), 1e-12)
    mid = 0.5 * (lo + hi)
    lo, hi = min(lo, mid - half), max(hi, mid + half)
    h, w = size
    ys, xs = np.mgrid[h / 16:h:h / 8, w / 16:w:w / 8]
    grid = np.column_stack([xs.ravel(), ys.ravel()])
    span = 0.0
    base, step = {}, {}
    for j, (A, a0, a1, a2) in coef.items():
        H0, e = pencils[j][:2]
        base[j] = H0 + np.outer(e, (a0, a1, a2))      # support j at the anchor's s = 0 (its s = a . x there)
        step[j] = A * np.outer(e, (0.0, 0.0, 1.0))
        d = np.linalg.norm(transfer(base[j], A * e, grid, np.full(len(grid), lo))
                           - transfer(base[j], A * e, grid, np.full(len(grid), hi)), axis=1) * grid_scale
        if np.isfinite(d).any():
            span = max(span, float(np.percentile(d[np.isfinite(d)], 90)))
    n = int(np.clip(np.ceil(span) + 1, min_planes, max_planes))
    return PencilSweep(base, step, np.linspace(lo, hi, n), anchor, left_out)
