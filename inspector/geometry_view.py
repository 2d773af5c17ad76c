"""The Geometry view's contents, from the pipeline's results: pure numpy, no viser.

What it shows is the set's reconstruction (pipeline/reconstruction.py `SetCameras`: K, R, C and
the sparse points) and each pair's geometry as the pipeline admitted it (support.PairGeometry:
F or H, its `source` and `uncertainty_px`). Nothing here estimates geometry; it only moves the
pipeline's cameras into a frame that is pleasant to look at and projects points and lines with
the pipeline's own matrices (pipeline.geometry.epipolar_lines, clip_line).

The display frame: the reconstruction's frame is arbitrary (COLMAP's), so it is rotated so that
the cameras' mean "up" is -y and their mean viewing direction +z (as the photo view, and
OpenCV's camera axes), centred on the sparse points' median and scaled so that the median
camera lies 1 unit from that centre. x_display = scale * rotation @ (X - centre).

A frustum's picture lies in its camera's plane z = `depth` (display units), centred on the
optical axis, with the photo's aspect: that is how viser draws a frustum's image once its scale
is set from `compute_canonical_frustum_size`. Pixels map to that plane by their position in the
picture (`pixel_on_plane`), so lines drawn there lie on the picture's content.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.geometry import clip_line, epipolar_lines
from pipeline.reconstruction import SetCameras

# Epipolar-line uncertainty (1 sigma, working px, the pipeline's uncertainty_px) in classes a
# person can tell apart: (upper bound, colour, words). The strip search looks a few px either
# side of the line, so below 2 px a line is as good as exact, beyond 6 px it can miss the match.
UNCERTAINTY_CLASSES = ((2.0, (0, 158, 115), "sure: ≤ 2 px"),
                       (6.0, (230, 159, 0), "2–6 px"),
                       (np.inf, (213, 40, 120), "uncertain: > 6 px"))
UNKNOWN_RGB = (120, 120, 120)          # no uncertainty estimate
REFERENCE_RGB = (20, 20, 20)           # the reference's frustum and its viewing ray
SUPPORT_RGB = (90, 110, 140)           # a support's frustum (its line carries the uncertainty colour)
OTHER_RGB = (185, 185, 185)            # a registered photo that is not a support of this reference


def uncertainty_colour(px: float) -> tuple[int, int, int]:
    """The colour of an epipolar-line uncertainty in px (grey when unknown, NaN)."""
    if not np.isfinite(px):
        return UNKNOWN_RGB
    return next(c for bound, c, _ in UNCERTAINTY_CLASSES if px <= bound)


def uncertainty_words(px: float) -> str:
    return "unknown" if not np.isfinite(px) else f"{px:.1f} px"


@dataclass(frozen=True)
class DisplayFrame:
    """x_display = scale * rotation @ (X - centre); rotation (3, 3) world -> display."""

    rotation: np.ndarray
    centre: np.ndarray
    scale: float

    def points(self, X: np.ndarray) -> np.ndarray:
        """(N, 3) world -> (N, 3) display."""
        return self.scale * (np.asarray(X, np.float64) - self.centre) @ self.rotation.T

    def camera_to_display(self, R: np.ndarray) -> np.ndarray:
        """(3, 3) world-to-camera rotation -> camera-to-display rotation."""
        return self.rotation @ R.T


def display_frame(cams: SetCameras) -> DisplayFrame:
    """The frame the Geometry view draws in (see the module docstring). Needs >= 1 camera."""
    reg = np.nonzero(cams.registered)[0]
    R = cams.R[reg]
    down = R[:, 1, :].mean(axis=0)            # camera +y (image down) in world coordinates
    forward = R[:, 2, :].mean(axis=0)
    down /= np.linalg.norm(down)
    forward = forward - (forward @ down) * down
    if np.linalg.norm(forward) < 1e-9:         # degenerate: take the first camera's axis
        forward = R[0, 2] - (R[0, 2] @ down) * down
    forward /= np.linalg.norm(forward)
    right = np.cross(down, forward)            # x = y × z: OpenCV's right-handed axes
    rotation = np.stack([right, down, forward])
    C = cams.C[reg]
    centre = np.median(cams.points, axis=0) if len(cams.points) else C.mean(axis=0)
    spread = float(np.median(np.linalg.norm(C - centre, axis=1)))
    return DisplayFrame(rotation, centre, 1.0 / spread if spread > 1e-12 else 1.0)


SAME_SPOT = 0.01       # display units (1 = the median camera's distance to the scene): one place


def frustum_depth(frame: DisplayFrame, cams: SetCameras) -> float:
    """Where the frustums' pictures lie (display units): a fifth of the cameras' spread, large
    enough to read in a view of all of them (pictures of nearby cameras may overlap: zoom in to
    tell them apart), between 0.05 and 0.15 (1 = the median camera's distance to the scene)."""
    C = frame.points(cams.C[cams.registered])
    if len(C) < 2:
        return 0.1
    spread = float(np.linalg.norm(C[:, None] - C[None], axis=-1).max())
    return float(np.clip(0.2 * spread, 0.05, 0.15))


@dataclass(frozen=True)
class Frustum:
    """One registered photo as viser draws it: fov (vertical, rad), aspect (w / h), the picture's
    depth, the camera's pose in the display frame (camera-to-display rotation, centre)."""

    photo: int
    fov: float
    aspect: float
    depth: float
    rotation: np.ndarray
    position: np.ndarray


REFERENCE_DEPTH = 0.6   # the reference's picture, relative to the others'


def frustums(cams: SetCameras, sizes: list[tuple[int, int]], frame: DisplayFrame, depth: float,
             ref: int | None = None) -> list[Frustum]:
    """A Frustum per registered photo. sizes: (h, w) working size per photo. The pictures lie at
    `depth`, the reference's nearer its camera (REFERENCE_DEPTH): seen over the reference's
    shoulder (overview_camera) it is then in front of the pictures of photos shot from about the
    same place, which would otherwise hide it, and it is the one to click."""
    out = []
    for k in np.nonzero(cams.registered)[0]:
        h, w = sizes[k]
        fov = 2.0 * float(np.arctan(0.5 * h / cams.K[k][1, 1]))
        out.append(Frustum(int(k), fov, w / h, REFERENCE_DEPTH * depth if k == ref else depth,
                           frame.camera_to_display(cams.R[k]), frame.points(cams.C[k][None])[0]))
    return out


def pixel_on_plane(f: Frustum, size: tuple[int, int], xy: np.ndarray, inset: float = 0.0) -> np.ndarray:
    """(N, 2) working pixels of photo f.photo -> (N, 3) display points on its frustum's picture
    (moved `inset` of the depth towards the camera, so that lines drawn there are not hidden by
    the picture)."""
    h, w = size
    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    z = f.depth * (1.0 - inset)
    half_h = z * np.tan(f.fov / 2.0)
    half_w = half_h * f.aspect
    local = np.column_stack([((xy[:, 0] + 0.5) / w - 0.5) * 2 * half_w, ((xy[:, 1] + 0.5) / h - 0.5) * 2 * half_h,
                             np.full(len(xy), z)])
    return local @ f.rotation.T + f.position


def plane_to_pixel(f: Frustum, size: tuple[int, int], origin, direction) -> np.ndarray | None:
    """Where a ray (display frame; a click) meets frustum f's picture, as a working pixel of
    photo f.photo, or None when it misses the picture."""
    o = (np.asarray(origin, np.float64) - f.position) @ f.rotation       # camera frame
    d = np.asarray(direction, np.float64) @ f.rotation
    if abs(d[2]) < 1e-12:
        return None
    t = (f.depth - o[2]) / d[2]
    if t <= 0:
        return None
    p = o + t * d
    h, w = size
    half_h = f.depth * np.tan(f.fov / 2.0)
    half_w = half_h * f.aspect
    u = (p[0] / (2 * half_w) + 0.5) * w - 0.5
    v = (p[1] / (2 * half_h) + 0.5) * h - 0.5
    if not (-0.5 <= u <= w - 0.5 and -0.5 <= v <= h - 0.5):
        return None
    return np.array([np.clip(u, 0, w - 1), np.clip(v, 0, h - 1)])


def viewing_ray(cams: SetCameras, frame: DisplayFrame, i: int, xy: np.ndarray, reach: float = 3.0) -> np.ndarray:
    """(3, 3) display points on the viewing ray of working pixel xy of photo i: the camera
    centre, and the points at the near and far ends of the scene's depth range in front of
    camera i (SetCameras.depth_range; depth along the optical axis). The far end stops `reach`
    display units from the scene's centre (a few far points can put it thousands of times
    farther than the rest of the scene)."""
    K, R, C = cams.K[i], cams.R[i], cams.C[i]
    ray = R.T @ np.linalg.solve(K, np.array([xy[0], xy[1], 1.0]))        # depth 1 along the axis
    near, far = cams.depth_range[i]
    if not (np.isfinite(near) and np.isfinite(far)):
        near, far = 0.0, float(np.median(cams.depth(i, cams.points))) * 2.0 if len(cams.points) else 1.0
    c, r = frame.points(C[None])[0], frame.scale * frame.rotation @ ray     # display: c + t r
    # the far end: no farther than where the ray leaves the sphere of radius `reach`
    b, cc = float(c @ r), float(c @ c) - reach ** 2
    disc = b * b - float(r @ r) * cc
    if disc > 0:
        far = min(far, max(near, (-b + np.sqrt(disc)) / float(r @ r)))
    return np.stack([c, c + near * r, c + far * r])


@dataclass(frozen=True)
class SupportLine:
    """What a reference pixel becomes in one support: its epipolar line (epipolar pairs; (2, 2)
    working pixels clipped to the photo, or None when the line misses it) or the point the
    homography puts it at (homography pairs; (2,)), with the pair's source and uncertainty."""

    sup: int
    kind: str                     # "epipolar" | "homography"
    source: str
    uncertainty_px: float
    segment: np.ndarray | None = None
    point: np.ndarray | None = None

    @property
    def colour(self) -> tuple[int, int, int]:
        return uncertainty_colour(self.uncertainty_px)


def support_lines(pairs: dict, ref: int, supports: list[int], sizes: list[tuple[int, int]],
                  xy: np.ndarray) -> list[SupportLine]:
    """For reference pixel xy: its epipolar line in every epipolar support (the pair's own F,
    pipeline.geometry.epipolar_lines) and its homography point in every homography support."""
    out = []
    for j in supports:
        g = pairs.get((ref, j))
        if g is None or not g.ok:
            continue
        if g.is_homography and g.H is not None:
            q = g.H @ np.array([xy[0], xy[1], 1.0])
            pt = q[:2] / q[2] if abs(q[2]) > 1e-12 else None
            out.append(SupportLine(j, "homography", g.source, g.uncertainty_px, point=pt))
        elif g.F is not None:
            seg = clip_line(epipolar_lines(g.F, np.asarray(xy, np.float64)[None])[0], sizes[j])
            out.append(SupportLine(j, "epipolar", g.source, g.uncertainty_px, segment=seg))
    return out


def cross(centre: np.ndarray, size: float) -> np.ndarray:
    """(2, 2, 2) two segments of a + of half-size `size` (pixels) around centre."""
    c = np.asarray(centre, np.float64)
    return np.array([[c - (size, 0), c + (size, 0)], [c - (0, size), c + (0, size)]])


def support_segments(lines: list[SupportLine], by_photo: dict[int, Frustum], sizes: list[tuple[int, int]],
                     inset: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """The support lines as 3-D segments on their frustums' pictures: ((S, 2, 3) display points,
    (S, 2, 3) uint8 colours); homography points as a cross. Photos without a frustum are left out."""
    segs, cols = [], []
    for ln in lines:
        f = by_photo.get(ln.sup)
        if f is None:
            continue
        h, w = sizes[ln.sup]
        if ln.segment is not None:
            px = np.asarray(ln.segment, np.float64)[None]
        elif ln.point is not None and np.all(np.isfinite(ln.point)):
            px = cross(ln.point, 0.04 * max(h, w))
        else:
            continue
        pts = pixel_on_plane(f, sizes[ln.sup], px.reshape(-1, 2), inset).reshape(-1, 2, 3)
        segs.append(pts)
        cols.append(np.broadcast_to(np.array(ln.colour, np.uint8), (len(pts), 2, 3)))
    if not segs:
        return np.zeros((0, 2, 3)), np.zeros((0, 2, 3), np.uint8)
    return np.concatenate(segs), np.concatenate(cols)


def scene_points(cams: SetCameras, frame: DisplayFrame, max_points: int = 20000,
                 keep: float = 0.98) -> tuple[np.ndarray, np.ndarray]:
    """The sparse points in the display frame with their colours ((N, 3) float32, (N, 3) uint8),
    without the farthest 2 % (a few stray points far away would shrink everything else) and at
    most max_points (an even subsample)."""
    if not len(cams.points):
        return np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint8)
    X = frame.points(cams.points)
    r = np.linalg.norm(X, axis=1)
    idx = np.nonzero(r <= np.quantile(r, keep))[0]
    if len(idx) > max_points:
        idx = idx[np.linspace(0, len(idx) - 1, max_points).astype(int)]
    return X[idx].astype(np.float32), np.asarray(cams.point_rgb[idx], np.uint8)


def overview_camera(frustum_list: list[Frustum], fov: float = np.deg2rad(75.0),
                    aspect: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """A viewpoint that shows the cameras with their pictures and the scene in front of them:
    (position, look_at) in the display frame. Behind the cameras' middle along their mean
    viewing direction (+z of the display frame) and a little above, so that the pictures face the
    viewer and the rays go away from it; far enough back that every camera is in view (fov: the
    viewer's vertical field of view, aspect: its width / height); looking a third of the way from the cameras to the scene's
    centre (the origin)."""
    if not frustum_list:
        return np.array([0.0, -0.5, -2.0]), np.zeros(3)
    C = np.array([f.position for f in frustum_list])
    mid = C.mean(axis=0)
    lateral = float(np.max(np.linalg.norm(C[:, :2] - mid[:2], axis=1)))      # across the view
    half = np.tan(fov / 2.0) * min(1.0, aspect)         # the narrower of the view's two half-widths
    back = max(1.15 * lateral / half, 4.0 * max(f.depth for f in frustum_list))
    away = np.array([0.0, -0.45, -1.0])                 # behind (-z) and above (-y)
    return mid + back * away / np.linalg.norm(away), mid - 0.33 * mid


def label_groups(frustum_list: list[Frustum], first: int | None = None) -> list[list[Frustum]]:
    """Frustums at one place (closer than SAME_SPOT: shots from one spot) share one label; the
    photo `first` leads its group."""
    order = sorted(frustum_list, key=lambda f: f.photo != first)
    groups: list[list[Frustum]] = []
    for f in order:
        g = next((g for g in groups if np.linalg.norm(g[0].position - f.position) < SAME_SPOT), None)
        if g is None:
            groups.append([f])
        else:
            g.append(f)
    return groups
