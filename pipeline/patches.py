"""Epipolar patches (§3.1.1): fans of epipolar strips in the reference, corresponding strips in the support.

Reference side. Epipolar lines are parametrised by their angle around the epipole e (paper §3.1.1).
We use half-lines (rays) from e so that an epipole inside the image is handled: the rays then
cover the full circle, otherwise the angular interval that sees the image. Adjacent rays at
angular step `dtheta` bound a strip; `n_fans` fans shifted by 0, 1/3, 2/3 of the step give the
overlap across lines. Along a strip, patches of length L start every L/3 (2/3 overlap), so each
pixel is covered by n_fans * 3 = 9 patches.

Each strip is sampled onto a grid in its own frame ("strip frame"): `rows` samples across (one per
sub-ray at angle theta_c + alpha * dtheta, alpha in (-1/2, 1/2)) by one sample per pixel along.
A patch is a window of that grid; descriptors of any window come from cumulative sums.

Support side. Row i of the corresponding strip is the epipolar line F p_i of a point p_i on
reference row i: exact, with no need for a finite support epipole. Candidates lie along the full
line (both sides of the support epipole). Rows are sampled across a normal of the central line.
Where the lines cross (at the support epipole) the strip is split into two segments. Epipolar
lines map to epipolar lines, so a static surface seen from the front in both images maps the
along direction with a sign fixed by the frames' handedness; each segment is traversed in the
direction that corresponds to "along" in the reference, so windows compare like with like.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from .jit import LazyKernel

FAR_FACTOR = 1e4     # an epipole farther than this many diagonals is moved to that distance


@dataclass(frozen=True)
class RefStrips:
    """All strips of all fans of one reference image for one pair.

    epipole: (2,) float64 finite epipole used for the fans (moved in from infinity if needed).
    circle: True when the rays cover the whole circle (epipole inside or near the image).
    theta_lo, dtheta: angles in radians; span: angular range covered (2*pi for a circle).
    Per strip s (arrays of length S): fan[s], k[s] (index within the fan), theta_c[s] (central
    angle), t0[s] (distance from e of the strip's first along sample), n_win[s] (patch count),
    offset[s] (index of its first sample in the flat along axis).
    L: patch length in pixels; stride = L // along_overlap; rows: samples across.
    """

    epipole: np.ndarray
    circle: bool
    theta_lo: float
    dtheta: float
    span: float
    n_fans: int
    n_per_fan: np.ndarray
    fan: np.ndarray
    k: np.ndarray
    theta_c: np.ndarray
    t0: np.ndarray
    n_win: np.ndarray
    offset: np.ndarray
    L: int
    stride: int
    rows: int

    @property
    def n_strips(self) -> int:
        return len(self.fan)

    @property
    def n_along(self) -> np.ndarray:
        return (self.n_win - 1) * self.stride + self.L

    @property
    def alphas(self) -> np.ndarray:
        return (np.arange(self.rows) + 0.5) / self.rows - 0.5

    def strip_index(self, theta_rel: np.ndarray, f: int) -> np.ndarray:
        """Strip number within fan f containing angles theta_rel (radians from theta_lo, in [0, 2pi))."""
        return _strip_index(theta_rel, f, self.circle, self.dtheta, self.n_fans, int(self.n_per_fan[f]))


def _strip_index(theta_rel: np.ndarray, f: int, circle: bool, dtheta: float, n_fans: int, n_in_fan: int) -> np.ndarray:
    # Fan f's boundaries sit at (k - o + f/n_fans) * dtheta from theta_lo; o = 1 leaves room for
    # a strip before the first image angle when the rays cover an interval.
    o = 0.0 if circle else 1.0
    k = np.floor(theta_rel / dtheta - f / n_fans + o).astype(np.int64)
    return k % n_in_fan if circle else k


def finite_epipole(e_h: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """(3,) homogeneous epipole -> (2,) finite point; an epipole at (or near) infinity is moved
    in to FAR_FACTOR diagonals from the image centre along its direction (lines then differ from
    parallel by < 1e-4 rad, under 0.1 px across the image)."""
    h, w = size
    c = np.array([(w - 1) / 2, (h - 1) / 2])
    far = FAR_FACTOR * np.hypot(w, h)
    d = e_h[:2]
    if abs(e_h[2]) * far > np.linalg.norm(d):
        p = d / e_h[2]
        if np.linalg.norm(p - c) <= far:
            return p
        d = p - c
    return c + d / np.linalg.norm(d) * far


def _image_corners(size: tuple[int, int], margin: float = 1.0) -> np.ndarray:
    h, w = size
    return np.array([[-margin, -margin], [w - 1 + margin, -margin], [w - 1 + margin, h - 1 + margin],
                     [-margin, h - 1 + margin]], dtype=np.float64)


def _line_box_interval(A: np.ndarray, B: np.ndarray, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Slab test: the parameter interval [t_in, t_out] where points A + t B (per row; A, B (N, 2))
    lie inside the image box (1 px margin). t_in > t_out when the line misses the box."""
    lo, hi = _image_corners(size)[0], _image_corners(size)[2]
    A = np.broadcast_to(A, B.shape)
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (lo[None] - A) / B
        t2 = (hi[None] - A) / B
    # a direction component of 0 leaves t unbounded on that axis only if A is inside the slab
    zero = np.abs(B) < 1e-15
    inside = (A >= lo[None]) & (A <= hi[None])
    tmin = np.where(zero, np.where(inside, -np.inf, np.inf), np.minimum(t1, t2))
    tmax = np.where(zero, np.where(inside, np.inf, -np.inf), np.maximum(t1, t2))
    return tmin.max(axis=1), tmax.min(axis=1)


def build_ref_strips(e_h: np.ndarray, size: tuple[int, int], L: int, along_overlap: int, rows: int,
                     n_fans: int, max_strips_per_fan: int = 720) -> RefStrips:
    """Fans of epipolar strips covering a reference image of size (h, w) around epipole e_h (3,)."""
    h, w = size
    e = finite_epipole(e_h, size)
    corners = _image_corners(size)
    c = np.array([(w - 1) / 2, (h - 1) / 2])
    diag = np.hypot(w, h)
    inside = bool(np.all(e >= corners[0] - L) and np.all(e <= corners[2] + L))
    ang = np.arctan2(corners[:, 1] - e[1], corners[:, 0] - e[0])
    if inside:
        circle, theta_lo, span = True, 0.0, 2 * np.pi
    else:
        # The image seen from an outside point spans less than pi: find the covering arc.
        a = np.sort(np.mod(ang, 2 * np.pi))
        gaps = np.diff(np.concatenate([a, [a[0] + 2 * np.pi]]))
        g = int(np.argmax(gaps))
        theta_lo = a[(g + 1) % 4]
        span = 2 * np.pi - gaps[g]
        circle = False
    # Strip height equals L at a typical distance from the epipole (§3.1.1 leaves the size open).
    r_ref = max(np.linalg.norm(c - e), 0.35 * diag)
    dtheta = L / r_ref
    if circle:
        m = int(min(max(np.ceil(2 * np.pi / dtheta), 8), max_strips_per_fan))
        dtheta = 2 * np.pi / m
        n_per_fan = np.full(n_fans, m)
    else:
        n_per_fan = np.array([int(np.ceil(span / dtheta - f / n_fans + 1)) for f in range(n_fans)])
        if n_per_fan.max() > max_strips_per_fan:
            dtheta = span / (max_strips_per_fan - 2)
            n_per_fan = np.array([int(np.ceil(span / dtheta - f / n_fans + 1)) for f in range(n_fans)])
    o = 0.0 if circle else 1.0
    fan = np.concatenate([np.full(n, f) for f, n in enumerate(n_per_fan)])
    k = np.concatenate([np.arange(n) for n in n_per_fan])
    theta_c = theta_lo + (k - o + fan / n_fans + 0.5) * dtheta
    # Along range of each strip: union over its two boundary rays, its central ray and corners.
    stride = L // along_overlap
    t_lo = np.full(len(k), np.inf)
    t_hi = np.full(len(k), -np.inf)
    for da in (-0.5, 0.0, 0.5):
        th = theta_c + da * dtheta
        dirs = np.stack([np.cos(th), np.sin(th)], axis=1)
        ti, to = _line_box_interval(e[None], dirs, size)
        ti = np.maximum(ti, 0.0)                 # rays: t >= 0
        hit = ti <= to
        # project onto the central direction: t_central = t * cos(da * dtheta)
        cs = np.cos(da * dtheta)
        t_lo = np.where(hit, np.minimum(t_lo, ti * cs), t_lo)
        t_hi = np.where(hit, np.maximum(t_hi, to * cs), t_hi)
    rel = np.mod(ang - theta_lo, 2 * np.pi)
    rc = np.linalg.norm(corners - e, axis=1)
    for f in range(n_fans):
        idx = np.nonzero(fan == f)[0]
        kc = _strip_index(rel, f, circle, dtheta, n_fans, int(n_per_fan[f]))
        for ci in range(4):
            if 0 <= kc[ci] < n_per_fan[f]:
                s = idx[kc[ci]]
                tc = rc[ci] * np.cos(ang[ci] - theta_c[s])
                t_lo[s], t_hi[s] = min(t_lo[s], tc), max(t_hi[s], tc)
    keep = np.isfinite(t_lo) & (t_hi > t_lo)
    # Windows start early enough that the first in-image pixel is covered by along_overlap patches.
    # Rays start at the epipole: samples at t < 0 would belong to the opposite ray.
    t0 = np.where(keep, np.maximum(np.floor(np.where(keep, t_lo, 0.0)) - (L - stride) - stride // 2, 0.0), 0.0)
    n_win = np.where(keep, np.ceil((np.where(keep, t_hi, 0.0) - t0) / stride), 0).astype(np.int64)
    n_win = np.maximum(n_win, 1) * keep
    sel = n_win > 0
    fan, k, theta_c, t0, n_win = fan[sel], k[sel], theta_c[sel], t0[sel], n_win[sel]
    n_along = (n_win - 1) * stride + L
    offset = np.concatenate([[0], np.cumsum(n_along)[:-1]]).astype(np.int64)
    return RefStrips(e, circle, float(theta_lo), float(dtheta), float(span), n_fans, n_per_fan, fan, k,
                     theta_c, t0, n_win.astype(np.int64), offset, L, stride, rows)


def iter_covering(st: RefStrips, size: tuple[int, int], points: np.ndarray | None = None):
    """For every pixel of an (h, w) reference image (or for the given (N, 2) points), the patches
    that cover it.

    Yields one (patch_id, ok, d2) triple per (fan, along offset), i.e. n_fans * along_overlap
    times: patch_id (h*w,) int64 index into the patch table (strip-major order, as in
    matching.match_pair), ok (h*w,) bool where that patch exists, and d2 (h*w,) float64 squared
    distance in pixels from the pixel to the patch centre.
    """
    if points is None:
        ys, xs = np.mgrid[0:size[0], 0:size[1]]
        xs, ys = xs.ravel(), ys.ravel()
    else:
        xs, ys = np.asarray(points, np.float64)[:, 0], np.asarray(points, np.float64)[:, 1]
    dx = xs - st.epipole[0]
    dy = ys - st.epipole[1]
    r = np.hypot(dx, dy)
    theta = np.arctan2(dy, dx)
    rel = np.mod(theta - st.theta_lo, 2 * np.pi)
    win_base = np.concatenate([[0], np.cumsum(st.n_win)[:-1]])
    n_patches = int(st.n_win.sum())
    for f in range(st.n_fans):
        lut = np.full(int(st.n_per_fan[f]), -1, np.int64)
        sel = np.nonzero(st.fan == f)[0]
        lut[st.k[sel]] = sel
        k = st.strip_index(rel, f)
        ok_f = (k >= 0) & (k < st.n_per_fan[f])
        s = np.where(ok_f, lut[np.clip(k, 0, len(lut) - 1)], -1)
        ok_f &= s >= 0
        s = np.maximum(s, 0)
        dth = theta - st.theta_c[s]
        t = r * np.cos(dth)
        u2 = (r * np.sin(dth)) ** 2
        j_hi = np.floor((t - st.t0[s]) / st.stride).astype(np.int64)
        for m in range(st.L // st.stride):
            j = j_hi - m
            ok = ok_f & (j >= 0) & (j < st.n_win[s]) & (t >= 0)
            pid = np.minimum(np.where(ok, win_base[s] + np.maximum(j, 0), 0), n_patches - 1)
            tc = st.t0[s] + j * st.stride + st.L / 2
            yield pid, ok, (t - tc) ** 2 + u2


def subset_strips(st: RefStrips, strip_ids: np.ndarray) -> RefStrips:
    """The same fans restricted to some strips (for explaining a few patches cheaply)."""
    ids = np.asarray(strip_ids, np.int64)
    n_along = st.n_along[ids]
    offset = np.concatenate([[0], np.cumsum(n_along)[:-1]]).astype(np.int64)
    return dataclasses.replace(st, fan=st.fan[ids], k=st.k[ids], theta_c=st.theta_c[ids], t0=st.t0[ids],
                               n_win=st.n_win[ids], offset=offset)


def patch_coverage(st: RefStrips, size: tuple[int, int]) -> np.ndarray:
    """(h, w) int32: number of reference patches covering each pixel (about 9, paper §4)."""
    count = np.zeros(size[0] * size[1], np.int32)
    for _, ok, _ in iter_covering(st, size):
        count += ok
    return count.reshape(size)


def ref_frames(st: RefStrips) -> tuple[np.ndarray, np.ndarray]:
    """Unit along (d) and across (n) directions per strip, (S, 2) each. Rows increase along n."""
    d = np.stack([np.cos(st.theta_c), np.sin(st.theta_c)], axis=1)
    n = np.stack([-d[:, 1], d[:, 0]], axis=1)
    return d, n


def ref_sample_points(st: RefStrips) -> tuple[np.ndarray, np.ndarray]:
    """Sample grid of all reference strips, concatenated along.

    Returns xy (rows, N, 2) float64 image positions and strip (N,) int strip id per along index,
    where N = sum of n_along. Row i lies on the ray at angle theta_c + alpha_i * dtheta.
    """
    n_along = st.n_along
    strip = np.repeat(np.arange(st.n_strips), n_along)
    t = st.t0[strip] + (np.arange(len(strip)) - st.offset[strip])
    d, n = ref_frames(st)
    tana = np.tan(st.alphas * st.dtheta)                       # (rows,)
    xy = (st.epipole[None, None, :] + t[None, :, None] * d[strip][None]
          + (t[None, :] * tana[:, None])[..., None] * n[strip][None])
    return xy, strip


def ref_patch_quads(st: RefStrips, strip: np.ndarray, start: np.ndarray) -> np.ndarray:
    """Corners of reference patches: (P, 4, 2) float32, for strips `strip` and along starts `start`
    (sample index within the strip). Order: near-left, far-left, far-right, near-right."""
    d, n = ref_frames(st)
    t_a = st.t0[strip] + start
    t_b = t_a + st.L
    half = np.tan(0.5 * st.dtheta)
    pts = []
    for t, side in ((t_a, -1), (t_b, -1), (t_b, 1), (t_a, 1)):
        pts.append(st.epipole + t[:, None] * d[strip] + (side * half * t)[:, None] * n[strip])
    return np.stack(pts, axis=1).astype(np.float32)


@dataclass(frozen=True)
class SupportSegments:
    """Corresponding strips in the support image, as segments of a flat along axis.

    For segment g (arrays of length G): strip[g] (reference strip id), offset[g] / length[g]
    (in the flat along axis), s0[g] and step[g] (= +1 or -1: along coordinate of the first sample
    and direction of traversal), and the strip's frame: foot[g] (2,) a point on the central
    line, d[g] (2,) along, n[g] (2,) across. bound_a/bound_b (G, 3): the strip's boundary lines
    (normalised a, b, c). row_lines: (G, rows, 3) the row lines. along_dir / across_dir (G, 2):
    the traversal direction and the direction of increasing row index; the frame
    (along_dir, across_dir) is right-handed, like the reference strips' frame.
    """

    strip: np.ndarray
    offset: np.ndarray
    length: np.ndarray
    s0: np.ndarray
    step: np.ndarray
    foot: np.ndarray
    d: np.ndarray
    n: np.ndarray
    bound_a: np.ndarray
    bound_b: np.ndarray
    row_lines: np.ndarray
    along_dir: np.ndarray
    across_dir: np.ndarray

    @property
    def n_total(self) -> int:
        return int(self.length.sum())


def _normalise_lines(l: np.ndarray) -> np.ndarray:
    return l / np.linalg.norm(l[..., :2], axis=-1, keepdims=True)


def _line_box_s(lines: np.ndarray, foot: np.ndarray, d: np.ndarray, n: np.ndarray,
                size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """For lines (S, 3) and per-strip frames, the along-coordinate interval where each line is in
    the image: the line point at along s is foot + s d + u n with u = -(l.(foot + s d)) / (l.n).
    Returns (s_min, s_max), NaN when the line misses the image."""
    # point(s) = foot + s d + u(s) n, u(s) = -(l0 + s l1) / ln  with l0 = l.foot1, l1 = l.d, ln = l.n
    l0 = lines[:, 0] * foot[:, 0] + lines[:, 1] * foot[:, 1] + lines[:, 2]
    l1 = lines[:, 0] * d[:, 0] + lines[:, 1] * d[:, 1]
    ln = lines[:, 0] * n[:, 0] + lines[:, 1] * n[:, 1]
    ln = np.where(np.abs(ln) < 1e-12, 1e-12, ln)
    # point(s) = A + s B with A = foot - l0/ln n, B = d - l1/ln n
    A = foot - (l0 / ln)[:, None] * n
    B = d - (l1 / ln)[:, None] * n
    ti, to = _line_box_interval(A, B, size)
    ok = ti <= to
    return np.where(ok, ti, np.nan), np.where(ok, to, np.nan)


def build_support_segments(F: np.ndarray, st: RefStrips, ref_size: tuple[int, int],
                           sup_size: tuple[int, int]) -> SupportSegments:
    """Corresponding strips in the support image for every reference strip of `st`."""
    h, w = sup_size
    d_r, n_r = ref_frames(st)
    # A point well inside each reference strip, used to pick the rows' epipolar lines.
    t_mid = st.t0 + 0.5 * st.n_along
    tana = np.tan(np.concatenate([[-0.5], st.alphas, [0.5]]) * st.dtheta)      # boundaries + rows
    pts = (st.epipole[None, None] + t_mid[:, None, None] * d_r[:, None]
           + (t_mid[:, None] * tana[None])[..., None] * n_r[:, None])          # (S, rows+2, 2)
    ph = np.concatenate([pts, np.ones((*pts.shape[:2], 1))], axis=-1)
    lines = _normalise_lines(ph @ F.T)                                         # (S, rows+2, 3)
    central = _normalise_lines((np.concatenate([st.epipole + t_mid[:, None] * d_r, np.ones((len(t_mid), 1))],
                                               axis=1)) @ F.T)
    d = np.stack([-central[:, 1], central[:, 0]], axis=1)
    n = central[:, :2].copy()
    c = np.array([(w - 1) / 2, (h - 1) / 2])
    foot = c[None] - (central @ np.array([c[0], c[1], 1.0]))[:, None] * n      # closest point to centre
    s_min = np.full(len(d), np.inf)
    s_max = np.full(len(d), -np.inf)
    for li in (0, (st.rows + 2) // 2, st.rows + 1):
        a, b = _line_box_s(lines[:, li], foot, d, n, sup_size)
        s_min = np.fmin(s_min, a)
        s_max = np.fmax(s_max, b)
    # Across offset of a line at along s in strip idx's frame: u = -(l.foot + s l.d) / (l.n).
    la, lb = lines[:, 0], lines[:, -1]

    def u_at(l: np.ndarray, s: np.ndarray, idx: np.ndarray) -> np.ndarray:
        f, dd, nn = foot[idx], d[idx], n[idx]
        ln = l[:, 0] * nn[:, 0] + l[:, 1] * nn[:, 1]
        ln = np.where(np.abs(ln) < 1e-12, 1e-12, ln)
        return -((l[:, 0] * f[:, 0] + l[:, 1] * f[:, 1] + l[:, 2]) + s * (l[:, 0] * dd[:, 0] + l[:, 1] * dd[:, 1])) / ln

    # The boundary lines cross at the support epipole: s* where u_a(s*) = u_b(s*).
    allidx = np.arange(len(d))
    zeros, ones = np.zeros(len(d)), np.ones(len(d))
    w0 = u_at(lb, zeros, allidx) - u_at(la, zeros, allidx)
    w1 = u_at(lb, ones, allidx) - u_at(la, ones, allidx)
    with np.errstate(divide="ignore", invalid="ignore"):
        s_cross = np.where(np.abs(w1 - w0) > 1e-15, -w0 / (w1 - w0), np.inf)
    seg_strip, seg_s0, seg_len, seg_step, seg_m = [], [], [], [], []
    valid = np.isfinite(s_min) & np.isfinite(s_max) & (s_max > s_min)
    for sid in np.nonzero(valid)[0]:
        lo_s, hi_s = np.floor(s_min[sid]), np.ceil(s_max[sid])
        pieces = [(lo_s, hi_s)]
        if lo_s < s_cross[sid] < hi_s:
            pieces = [(lo_s, np.floor(s_cross[sid])), (np.floor(s_cross[sid]) + 1, hi_s)]
        for a, b in pieces:
            if b - a < 2:
                continue
            mid = 0.5 * (a + b)
            width = w0[sid] + mid * (w1[sid] - w0[sid])          # linear in s
            # Frame (d, m) with m = sign(width) n; its handedness det[d, m] sets the traversal.
            hand = np.sign(width) * (d[sid, 0] * n[sid, 1] - d[sid, 1] * n[sid, 0])
            step = 1 if hand > 0 else -1
            seg_strip.append(sid)
            seg_len.append(int(b - a + 1))
            seg_s0.append(a if step > 0 else b)
            seg_step.append(step)
            seg_m.append(np.sign(width) if width != 0 else 1.0)
    seg_strip = np.array(seg_strip, dtype=np.int64)
    seg_len = np.array(seg_len, dtype=np.int64)
    offset = np.concatenate([[0], np.cumsum(seg_len)[:-1]]).astype(np.int64) if len(seg_len) else np.zeros(0, np.int64)
    step_a = np.array(seg_step, dtype=np.float64)
    m_a = np.array(seg_m, dtype=np.float64)
    return SupportSegments(seg_strip, offset, seg_len, np.array(seg_s0, dtype=np.float64), step_a,
                           foot[seg_strip], d[seg_strip], n[seg_strip], lines[seg_strip, 0], lines[seg_strip, -1],
                           lines[seg_strip, 1:-1], step_a[:, None] * d[seg_strip], m_a[:, None] * n[seg_strip])


def support_sample_points(sg: SupportSegments) -> tuple[np.ndarray, np.ndarray]:
    """Sample grid of all support segments: xy (rows, N, 2) float64 and segment id (N,) per along index.

    Sample i of segment g lies on the central line at s = s0 + step (i - offset), and row r where
    the normal through it meets row line r. One compiled pass (numba), the same arithmetic as
    numpy's in the same order, so the same bits (tests/test_patches.py): numpy's gathers of every
    sample's row lines made (N, rows, 3) temporaries, 13 ms a pair against 0.6 ms."""
    return _sample_kernel(sg.s0.astype(np.float64), sg.step.astype(np.float64), sg.offset.astype(np.int64),
                          sg.length.astype(np.int64), np.ascontiguousarray(sg.foot, np.float64),
                          np.ascontiguousarray(sg.d, np.float64), np.ascontiguousarray(sg.n, np.float64),
                          np.ascontiguousarray(sg.row_lines, np.float64))


def _sample_numba():
    import numba

    @numba.njit(cache=True, nogil=True)          # no fastmath: the same bits as numpy's
    def kernel(s0, step, offset, length, foot, d, n, row_lines):
        N = 0
        for g in range(len(length)):
            N += length[g]
        rows = row_lines.shape[1]
        xy = np.empty((rows, N, 2))
        seg = np.empty(N, np.int64)
        i = 0
        for g in range(len(length)):
            for _ in range(length[g]):
                seg[i] = g
                s = s0[g] + step[g] * (i - offset[g])
                bx = foot[g, 0] + s * d[g, 0]
                by = foot[g, 1] + s * d[g, 1]
                for r in range(rows):
                    l0, l1, l2 = row_lines[g, r, 0], row_lines[g, r, 1], row_lines[g, r, 2]
                    num = l0 * bx + l1 * by + l2
                    den = l0 * n[g, 0] + l1 * n[g, 1]
                    u = -num / (1e-12 if abs(den) < 1e-12 else den)
                    xy[r, i, 0] = bx + u * n[g, 0]
                    xy[r, i, 1] = by + u * n[g, 1]
                i += 1
        return xy, seg
    return kernel


_sample_kernel = LazyKernel(_sample_numba)


def support_quads(sg: SupportSegments, seg: np.ndarray, start: np.ndarray, length: np.ndarray) -> np.ndarray:
    """Corners of candidate patches (C, 4, 2) float32 for segments `seg`, along starts and lengths."""
    out = []
    for s_idx, bound in ((start, sg.bound_a), (start + length, sg.bound_a), (start + length, sg.bound_b),
                         (start, sg.bound_b)):
        s = sg.s0[seg] + sg.step[seg] * s_idx
        base = sg.foot[seg] + s[:, None] * sg.d[seg]
        l = bound[seg]
        u = -(l[:, 0] * base[:, 0] + l[:, 1] * base[:, 1] + l[:, 2]) / np.where(
            np.abs(l[:, 0] * sg.n[seg][:, 0] + l[:, 1] * sg.n[seg][:, 1]) < 1e-12, 1e-12,
            l[:, 0] * sg.n[seg][:, 0] + l[:, 1] * sg.n[seg][:, 1])
        out.append(base + u[:, None] * sg.n[seg])
    return np.stack(out, axis=1).astype(np.float32)
