"""Synthetic CrowdCam sets: a textured 3-D scene shot by hand-held "phones" at different moments.

A small numpy ray caster renders quads (ground, facades, boxes) and ellipsoids (people's limbs,
balls, tree crowns) with procedural textures and sun shading, at 2x2 supersampling. Each camera
has its own position, height, focal length, image size, roll, white balance, exposure, gamma,
vignetting, noise and JPEG quality, and takes its photo at its own moment, so the movers (walking
people with swinging limbs, turning; a rolling ball) are elsewhere and posed differently in every
photo. Ground truth comes from the renderer: 255 where a pixel is fully covered by a mover, 128
on the mover's boundary pixels (partly covered: don't care), 0 elsewhere. `cameras.json` holds
every camera's K, R, C and its shot time, so tests can compare estimated F with the true one;
`scene_and_cameras` rebuilds a set's scene and cameras, and `render_depth` its depth and movers,
for the evaluation against the truth (crowdcam/truth.py).

`crowdcam make-samples` re-renders the bundled sets (deterministic per seed).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import cv2
import numpy as np

SS = 2       # supersampling factor per axis


# ----------------------------------------------------------------------------- textures
def _value_noise(rng: np.random.Generator, size: int, cells: int, channels: int = 1) -> np.ndarray:
    """Seamless (tileable) smooth noise in [0, 1]: (size, size, channels) float32."""
    g = rng.random((cells, cells, channels)).astype(np.float32)
    pad = np.pad(g, ((2, 2), (2, 2), (0, 0)), mode="wrap")
    scale = size / cells
    big = cv2.resize(pad, (int(round((cells + 4) * scale)),) * 2, interpolation=cv2.INTER_CUBIC)
    o = int(round(2 * scale))
    big = big.reshape(big.shape[0], big.shape[1], channels)
    return np.clip(big[o:o + size, o:o + size], 0, 1)


def _fbm(rng, size, octaves=(4, 8, 16, 32, 64), channels=1) -> np.ndarray:
    out = np.zeros((size, size, channels), np.float32)
    amp, tot = 1.0, 0.0
    for c in octaves:
        out += amp * _value_noise(rng, size, c, channels)
        tot += amp
        amp *= 0.6
    return out / tot


def _graffiti(rng, size: int, pattern: "Stones", extent: tuple[float, float]) -> np.ndarray:
    """Render a procedural pattern once over a whole surface of `extent` metres and spray tags on it."""
    h = int(size * extent[1] / extent[0])
    vv, uu = np.mgrid[0:h, 0:size]
    img = pattern((uu.ravel() + 0.5) / size * extent[0], (vv.ravel() + 0.5) / h * extent[1]).reshape(h, size, 3)
    img = np.ascontiguousarray(img.astype(np.float32))
    for _ in range(int(extent[0] * 1.2)):
        pts = np.cumsum(rng.normal(0, h / 12, (8, 2)), axis=0) + [rng.integers(0, size), rng.integers(h // 2, h)]
        cv2.polylines(img, [pts.astype(np.int32)], False, rng.random(3).tolist(), int(rng.integers(2, 6)), cv2.LINE_AA)
    return np.clip(img, 0, 1)


def tex_wood(rng, size=512, base=(0.55, 0.36, 0.2)) -> np.ndarray:
    n = _fbm(rng, size, (4, 16, 64))[..., 0]
    y = np.arange(size)[:, None] / size
    rings = 0.5 + 0.5 * np.sin(2 * np.pi * (12 * y + 3 * n))
    v = 0.7 + 0.35 * rings
    return np.clip(np.array(base)[None, None] * v[..., None] * (0.85 + 0.3 * n[..., None]), 0, 1)


def tex_posters(rng, size=512, background=(0.85, 0.83, 0.78)) -> np.ndarray:
    img = np.ones((size, size, 3), np.float32) * np.array(background)
    for _ in range(60):
        col = rng.random(3) ** 0.7
        kind = rng.integers(3)
        x, y = rng.integers(0, size, 2)
        s = int(rng.integers(size // 40, size // 7))
        if kind == 0:
            cv2.circle(img, (int(x), int(y)), s, col.tolist(), -1, cv2.LINE_AA)
        elif kind == 1:
            cv2.rectangle(img, (int(x), int(y)), (int(x + 1.5 * s), int(y + s)), col.tolist(), -1)
        else:
            pts = rng.integers(-s, s, (3, 2)) + np.array([x, y])
            cv2.fillConvexPoly(img, pts.astype(np.int32), col.tolist(), cv2.LINE_AA)
    img *= 0.85 + 0.3 * _fbm(rng, size, (16, 64))
    return np.clip(img, 0, 1)


def tex_facade(rng, size=512, wall=(0.8, 0.72, 0.6), floors=4, bays=5) -> np.ndarray:
    img = np.ones((size, size, 3), np.float32) * np.array(wall)
    img *= 0.85 + 0.3 * _fbm(rng, size, (8, 32, 128))
    fh, bw = size // floors, size // bays
    frame = np.array(wall) * 0.6
    for f in range(floors):
        for b in range(bays):
            x0, y0 = b * bw + bw // 4, f * fh + fh // 5
            x1, y1 = x0 + bw // 2, y0 + int(fh * 0.55)
            glass = np.array([0.25, 0.3, 0.38]) * rng.uniform(0.6, 1.3)
            cv2.rectangle(img, (x0 - 4, y0 - 4), (x1 + 4, y1 + 4), frame.tolist(), -1)
            cv2.rectangle(img, (x0, y0), (x1, y1), glass.tolist(), -1)
            cv2.line(img, ((x0 + x1) // 2, y0), ((x0 + x1) // 2, y1), frame.tolist(), 3)
            if rng.random() < 0.25:    # balconies with plants and awnings make bays distinct
                cv2.rectangle(img, (x0 - 8, y1 - 6), (x1 + 8, y1 + 14), (rng.random(3) * 0.9).tolist(), -1)
            if rng.random() < 0.5:     # curtains / reflections make windows distinct
                cv2.rectangle(img, (x0, y0), (x0 + (x1 - x0) // 3, y1), (rng.random(3) * 0.8).tolist(), -1)
            cv2.rectangle(img, (x0 - 6, y1 + 4), (x1 + 6, y1 + 10), (np.array(wall) * 1.1).clip(0, 1).tolist(), -1)
    # a shop front with signs on the ground floor
    y0 = size - fh
    signs = tex_posters(rng, size)[: fh // 3]
    img[y0: y0 + fh // 3] = signs
    return np.clip(img, 0, 1)


def tex_cloth(rng, size=128, color=(0.2, 0.3, 0.7), stripes: bool = False) -> np.ndarray:
    n = _fbm(rng, size, (4, 16, 64))
    img = np.array(color)[None, None] * (0.75 + 0.5 * n)
    if stripes:
        y = np.arange(size)[:, None]
        img = img * (0.7 + 0.3 * ((y // (size // 8)) % 2))[..., None]
    return np.clip(img.astype(np.float32), 0, 1)


def tex_ball(rng, size=256) -> np.ndarray:
    lon = np.arange(size)[None, :] / size
    lat = np.arange(size)[:, None] / size
    seg = (np.floor(lon * 6).astype(int) + 0 * lat.astype(int)) % 6
    cols = np.array([[0.9, 0.15, 0.1], [0.95, 0.85, 0.1], [0.1, 0.4, 0.85], [0.95, 0.95, 0.95],
                     [0.1, 0.65, 0.25], [0.95, 0.5, 0.1]])
    img = cols[seg].astype(np.float32)
    for _ in range(25):
        cv2.circle(img, tuple(int(v) for v in rng.integers(0, size, 2)), int(rng.integers(4, 12)),
                   (rng.random(3)).tolist(), -1, cv2.LINE_AA)
    return img


def tex_foliage(rng, size=256) -> np.ndarray:
    n = _fbm(rng, size, (8, 32, 64), 3)
    return np.clip(np.array([0.18, 0.38, 0.12]) * (0.5 + 1.0 * n), 0, 1).astype(np.float32)


@dataclass(frozen=True)
class Stones:
    """A non-periodic running-bond pattern in world units (metres): every stone gets its own
    shade from a hash of its row and column, and a fine noise texture adds grain. Real paving and
    brick walls repeat a shape, never an exact image; exact texture tiling made SIFT match the
    wrong tile and broke the geometry, which is not what a CrowdCam set looks like."""
    size: tuple[float, float]
    base: tuple[float, float, float]
    grain: np.ndarray
    seed: float
    joint: float = 0.06
    var: float = 0.45

    def __call__(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        su, sv = self.size
        row = np.floor(v / sv)
        off = 0.5 * su * (row % 2)
        col = np.floor((u + off) / su)

        def h(k):
            return np.mod(np.sin(row * 12.9898 + col * 78.233 + self.seed * 3.7 + k * 19.19) * 43758.5453, 1.0)
        shade = (1 - self.var / 2) + self.var * h(0)
        tint = 1 + 0.08 * (np.stack([h(1), h(2), h(3)], axis=1) - 0.5)
        fu, fv = np.mod((u + off) / su, 1.0), np.mod(v / sv, 1.0)
        jt = self.joint
        joint = np.where((fu < jt * sv / su) | (fv < jt), 0.45, 1.0)
        grain = _sample(self.grain, u / 1.7, v / 1.7)
        return np.array(self.base) * (shade * joint)[:, None] * tint * (0.7 + 0.6 * grain)


def stones(rng, size, base, var=0.45, joint=0.06) -> Stones:
    return Stones(size, base, _fbm(rng, 256, (8, 32, 64), 3), float(rng.uniform(0, 100)), joint, var)


def tex_plain(rng, color, size=64, var=0.2) -> np.ndarray:
    return np.clip(np.array(color) * (1 - var / 2 + var * _fbm(rng, size, (4, 16))), 0, 1).astype(np.float32)


# ----------------------------------------------------------------------------- scene
@dataclass
class Quad:
    """Rectangle origin + a*eu + b*ev, a, b in [0, 1]; texture repeats every `tile` metres."""
    origin: np.ndarray
    eu: np.ndarray
    ev: np.ndarray
    tex: str
    tile: float | tuple[float, float] = 1.0
    moving: bool = False

    @property
    def tiles(self) -> tuple[float, float]:
        return self.tile if isinstance(self.tile, tuple) else (self.tile, self.tile)


@dataclass
class Ellipsoid:
    centre: np.ndarray
    R: np.ndarray          # columns: local axes in world
    radii: np.ndarray
    tex: str
    moving: bool = False


@dataclass
class Scene:
    prims: list = field(default_factory=list)
    textures: dict = field(default_factory=dict)
    sun: np.ndarray = field(default_factory=lambda: _unit(np.array([0.4, -0.3, 0.85])))
    sky: tuple = ((0.55, 0.7, 0.95), (0.85, 0.9, 0.98))

    def quad(self, *a, **k):
        self.prims.append(Quad(*[np.asarray(v, float) if i < 3 else v for i, v in enumerate(a)], **k))

    def box(self, centre, size, yaw, tex, tile=1.0, moving=False, top_tex=None):
        c, (sx, sy, sz) = np.asarray(centre, float), size
        R = _rot_z(yaw)
        ax, ay, az = R[:, 0] * sx, R[:, 1] * sy, R[:, 2] * sz
        o = c - (ax + ay) / 2
        self.prims += [Quad(o, ax, az, tex, tile, moving), Quad(o + ay, ax, az, tex, tile, moving),
                       Quad(o, ay, az, tex, tile, moving), Quad(o + ax, ay, az, tex, tile, moving),
                       Quad(o + az, ax, ay, top_tex or tex, tile, moving)]

    def ellipsoid(self, centre, R, radii, tex, moving=False):
        self.prims.append(Ellipsoid(np.asarray(centre, float), np.asarray(R, float), np.asarray(radii, float), tex, moving))


def _unit(v):
    return v / np.linalg.norm(v)


def _rot_z(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def _rot_y(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rot_axis(axis, a):
    axis = _unit(np.asarray(axis, float))
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * K @ K


def add_person(scene: Scene, pos, heading, t, shirt, trousers, height=1.75, walking=True, phase=0.0, moving=True):
    """A person as seven ellipsoids; limbs swing with time while walking (non-rigid)."""
    k = height / 1.75
    Rz = _rot_z(heading)
    swing = 0.5 * np.sin(2 * np.pi * 0.9 * t + phase) if walking else 0.05
    p = np.array([pos[0], pos[1], 0.0])

    def at(local):
        return p + Rz @ (np.asarray(local) * k)
    scene.ellipsoid(at([0, 0, 1.22]), Rz, np.array([0.13, 0.21, 0.33]) * k, shirt, moving)
    scene.ellipsoid(at([0, 0, 1.64]), Rz, np.array([0.1, 0.09, 0.12]) * k, "skin", moving)
    for side, sgn in ((0.1, 1), (-0.1, -1)):
        R = Rz @ _rot_y(sgn * swing)
        scene.ellipsoid(at([0, side, 0.9]) + R @ np.array([0, 0, -0.45 * k]), R, np.array([0.08, 0.08, 0.47]) * k,
                        trousers, moving)
        Ra = Rz @ _rot_y(-sgn * swing * 0.8)
        scene.ellipsoid(at([0, side * 2.6, 1.45]) + Ra @ np.array([0, 0, -0.3 * k]), Ra,
                        np.array([0.055, 0.055, 0.32]) * k, shirt, moving)


def add_tree(scene: Scene, pos, h=5.0):
    scene.box([pos[0], pos[1], 0], (0.3, 0.3, h * 0.55), 0.3, "bark")
    scene.ellipsoid([pos[0], pos[1], h * 0.7], np.eye(3), np.array([1.6, 1.6, 1.5]) * h / 5, "foliage")


# ----------------------------------------------------------------------------- camera and rendering
@dataclass(frozen=True)
class Camera:
    K: np.ndarray
    R: np.ndarray       # world -> camera rotation (rows: right, down, forward)
    C: np.ndarray
    size: tuple[int, int]   # (h, w)

    @property
    def P(self) -> np.ndarray:
        return self.K @ np.hstack([self.R, -self.R @ self.C[:, None]])


def look_at(C, target, f, size, roll=0.0) -> Camera:
    C, target = np.asarray(C, float), np.asarray(target, float)
    fwd = _unit(target - C)
    right = _unit(np.cross(fwd, [0, 0, 1.0]))
    down = np.cross(fwd, right)
    R = _roll(np.stack([right, down, fwd]), roll)
    h, w = size
    K = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1.0]])
    return Camera(K, R, C, size)


def _roll(R, a):
    """Rotate the camera about its optical axis by a radians."""
    c, s = np.cos(a), np.sin(a)
    Rr = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    return Rr @ R


def _sample(tex, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Bilinear, wrapping texture lookup at texture coordinates (u, v) in tiles; a callable
    texture (procedural, in metres) is evaluated directly."""
    if callable(tex):
        return tex(u, v)
    th, tw = tex.shape[:2]
    x = np.mod(u, 1.0) * tw - 0.5
    y = np.mod(v, 1.0) * th - 0.5
    x0, y0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    x0, y0, x1, y1 = x0 % tw, y0 % th, (x0 + 1) % tw, (y0 + 1) % th
    return ((tex[y0, x0] * (1 - fx) + tex[y0, x1] * fx) * (1 - fy) + (tex[y1, x0] * (1 - fx) + tex[y1, x1] * fx) * fy)


def _intersect(prim, o, d):
    """Ray parameter t (inf when missed), texture (u, v) and world normal for rays o + t d."""
    n_rays = len(d)
    if isinstance(prim, Quad):
        n = np.cross(prim.eu, prim.ev)
        n = n / np.linalg.norm(n)
        den = d @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((prim.origin - o) @ n) / den
        p = o + t[:, None] * d
        rel = p - prim.origin
        a = rel @ prim.eu / (prim.eu @ prim.eu)
        b = rel @ prim.ev / (prim.ev @ prim.ev)
        hit = (t > 1e-4) & (a >= 0) & (a <= 1) & (b >= 0) & (b <= 1) & np.isfinite(t)
        t = np.where(hit, t, np.inf)
        tu, tv = prim.tiles
        uv = (a * np.linalg.norm(prim.eu) / tu, b * np.linalg.norm(prim.ev) / tv)
        normal = np.broadcast_to(n, (n_rays, 3))
        return t, uv, normal
    # ellipsoid: into unit-sphere space (all rays share the camera centre o)
    ol = np.broadcast_to(((o - prim.centre) @ prim.R) / prim.radii, d.shape)
    dl = (d @ prim.R) / prim.radii
    A = np.sum(dl * dl, axis=1)
    B = 2 * np.sum(ol * dl, axis=1)
    Cc = np.sum(ol * ol, axis=1) - 1
    disc = B * B - 4 * A * Cc
    sq = np.sqrt(np.maximum(disc, 0))
    t1 = (-B - sq) / (2 * A)
    t2 = (-B + sq) / (2 * A)
    t = np.where(t1 > 1e-4, t1, t2)
    hit = (disc > 0) & (t > 1e-4)
    t = np.where(hit, t, np.inf)
    pl = ol + np.where(hit, t, 0)[:, None] * dl
    normal = (pl / prim.radii) @ prim.R.T
    normal /= np.linalg.norm(normal, axis=1, keepdims=True) + 1e-12
    u = (np.arctan2(pl[:, 1], pl[:, 0]) / (2 * np.pi)) % 1.0
    v = np.arccos(np.clip(pl[:, 2], -1, 1)) / np.pi
    return t, (u, v), normal


def _corners(prim) -> np.ndarray:
    if isinstance(prim, Quad):
        o, a, b = prim.origin, prim.eu, prim.ev
        return np.array([o, o + a, o + b, o + a + b])
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    return prim.centre + (signs * prim.radii) @ prim.R.T


def _candidate_rays(prim, cam: Camera, grid: np.ndarray, ss: int = SS) -> np.ndarray:
    """Indices of the rays (`ss` x `ss` per pixel) inside the primitive's projected bounding box."""
    X = _corners(prim)
    xc = (X - cam.C) @ cam.R.T
    if np.any(xc[:, 2] <= 1e-3):
        return grid.ravel()       # straddles the camera plane: test every ray
    uv = (xc @ cam.K.T)[:, :2] / xc[:, 2:3]
    lo = np.floor((uv.min(axis=0) + 0.5) * ss - 1).astype(int)
    hi = np.ceil((uv.max(axis=0) + 0.5) * ss + 1).astype(int)
    x0, y0 = max(lo[0], 0), max(lo[1], 0)
    x1, y1 = min(hi[0], grid.shape[1]), min(hi[1], grid.shape[0])
    if x1 <= x0 or y1 <= y0:
        return np.zeros(0, np.int64)
    return grid[y0:y1, x0:x1].ravel()


def render(scene: Scene, cam: Camera) -> tuple[np.ndarray, np.ndarray]:
    """Linear RGB (h, w, 3) float32 and mover coverage (h, w) float32 in [0, 1]."""
    h, w = cam.size
    ys, xs = np.mgrid[0:h * SS, 0:w * SS]
    u = (xs.ravel() + 0.5) / SS - 0.5
    v = (ys.ravel() + 0.5) / SS - 0.5
    rays = np.stack([u, v, np.ones_like(u)], axis=1) @ np.linalg.inv(cam.K).T @ cam.R
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    best_t = np.full(len(rays), np.inf)
    best_id = np.full(len(rays), -1)
    grid = np.arange(len(rays)).reshape(h * SS, w * SS)
    for k, prim in enumerate(scene.prims):
        idx = _candidate_rays(prim, cam, grid)
        t, _, _ = _intersect(prim, cam.C, rays[idx])
        closer = t < best_t[idx]
        best_t[idx[closer]] = t[closer]
        best_id[idx[closer]] = k
    # sky
    up = np.clip(rays[:, 2], 0, 1)[:, None]
    rgb = (np.array(scene.sky[1]) * (1 - up) + np.array(scene.sky[0]) * up).astype(np.float32)
    moving = np.zeros(len(rays), np.float32)
    for k, prim in enumerate(scene.prims):
        sel = np.nonzero(best_id == k)[0]
        if len(sel) == 0:
            continue
        t, (tu, tv), nrm = _intersect(prim, cam.C, rays[sel])
        nrm = np.array(nrm)
        facing = np.sum(nrm * rays[sel], axis=1) > 0
        nrm[facing] *= -1                                   # two-sided surfaces
        col = _sample(scene.textures[prim.tex], tu, tv)
        shade = 0.45 + 0.75 * np.clip(nrm @ scene.sun, 0, 1)
        rgb[sel] = col * shade[:, None]
        if prim.moving:
            moving[sel] = 1.0
    rgb = rgb.reshape(h * SS, w * SS, 3)
    rgb = cv2.resize(rgb, (w, h), interpolation=cv2.INTER_AREA)
    cov = cv2.resize(moving.reshape(h * SS, w * SS), (w, h), interpolation=cv2.INTER_AREA)
    return rgb, cov


def render_depth(scene: Scene, cam: Camera) -> tuple[np.ndarray, np.ndarray]:
    """Depth and movers at the pixel centres, one ray per pixel (for evaluation, not for photos).

    Returns depth (h, w) float32: z in the camera frame (distance along the optical axis) of the
    first hit, inf where the ray sees sky; and moving (h, w) bool: the first hit is a moving
    primitive. The world point of pixel (u, v) is C + depth * R^T K^-1 (u, v, 1).
    """
    h, w = cam.size
    ys, xs = np.mgrid[0:h, 0:w]
    pix = np.stack([xs.ravel(), ys.ravel(), np.ones(h * w)], axis=1).astype(np.float64)
    # Rays scaled so that their camera-frame z is 1: the ray parameter t is then the depth itself.
    rays = pix @ np.linalg.inv(cam.K).T @ cam.R
    best_t = np.full(h * w, np.inf)
    moving = np.zeros(h * w, bool)
    grid = np.arange(h * w).reshape(h, w)
    for prim in scene.prims:
        idx = _candidate_rays(prim, cam, grid, ss=1)
        if len(idx) == 0:
            continue
        t, _, _ = _intersect(prim, cam.C, rays[idx])
        closer = t < best_t[idx]
        best_t[idx[closer]] = t[closer]
        moving[idx[closer]] = prim.moving
    return best_t.reshape(h, w).astype(np.float32), moving.reshape(h, w)


@dataclass(frozen=True)
class Look:
    """Per-camera photometry: white balance gains, exposure, gamma, vignetting, noise, JPEG quality."""
    wb: tuple[float, float, float]
    exposure: float
    gamma: float
    vignette: float
    noise: float
    jpeg: int


def random_look(rng: np.random.Generator, strength: float = 1.0) -> Look:
    wb = 1 + strength * rng.uniform(-0.12, 0.12, 3)
    return Look(tuple(float(x) for x in wb / wb.mean()), float(max(0.4, 1 + strength * rng.uniform(-0.25, 0.2))),
                float(1 + strength * rng.uniform(-0.12, 0.12)), float(rng.uniform(0.05, 0.3)),
                float(rng.uniform(1.0, 2.5)), int(rng.integers(85, 94)))


def develop(rgb_lin: np.ndarray, look: Look, rng: np.random.Generator) -> np.ndarray:
    """Linear render -> 8-bit photo (RGB) with the camera's look."""
    h, w = rgb_lin.shape[:2]
    yy, xx = np.mgrid[0:h, 0:w]
    r2 = ((xx - w / 2) ** 2 + (yy - h / 2) ** 2) / ((w / 2) ** 2 + (h / 2) ** 2)
    img = rgb_lin * np.array(look.wb)[None, None] * look.exposure * (1 - look.vignette * r2)[..., None]
    img = np.clip(img, 0, 1) ** (1 / (1.0 * look.gamma))
    img = cv2.GaussianBlur(img.astype(np.float32), (0, 0), 0.5)
    img = img * 255 + rng.normal(0, look.noise, img.shape)
    return np.clip(img + 0.5, 0, 255).astype(np.uint8)


# ----------------------------------------------------------------------------- sets
@dataclass(frozen=True)
class SetSpec:
    name: str
    description: str
    n_cameras: int
    seed: int
    build: Callable[[np.random.Generator], tuple[Callable[[float], Scene], list[Camera], list[float]]]
    look_strength: float = 1.0     # scales the cameras' colour and exposure differences
    bundled: bool = True           # rendered by `make-samples` by default and shipped in sample_sets/


def _square_textures(rng) -> dict:
    return {"paving": stones(rng, (0.6, 0.4), (0.55, 0.52, 0.48)),
            "facade_a": tex_facade(rng, 1024, wall=(0.82, 0.74, 0.6), floors=4, bays=5),
            "facade_b": tex_facade(rng, 1024, wall=(0.7, 0.75, 0.8), floors=3, bays=5),
            "facade_c": tex_facade(rng, 1024, wall=(0.85, 0.62, 0.5), floors=3, bays=14),
            "bricks": _graffiti(rng, 2048, stones(rng, (0.25, 0.07), (0.62, 0.3, 0.22), var=0.35, joint=0.12),
                                (34.0, 8.0)),
            "posters": tex_posters(rng, 1024), "wood": tex_wood(rng),
            "bark": tex_plain(rng, (0.35, 0.25, 0.18), var=0.5), "foliage": tex_foliage(rng),
            "skin": tex_plain(rng, (0.85, 0.65, 0.5), var=0.1),
            "metal": tex_plain(rng, (0.3, 0.32, 0.35), var=0.3)}


def _square_static(scene: Scene) -> None:
    """A town square: paving, three facades, a kiosk, benches, trees."""
    scene.quad([-20, -20, 0], [40, 0, 0], [0, 40, 0], "paving", tile=1.0)
    scene.quad([-14, 14, 0], [14, 0, 0], [0, 0, 12], "facade_a", tile=(14.0, 12.0))
    scene.quad([0, 14, 0], [14, 0, 0], [0, 0, 10], "facade_b", tile=(14.0, 10.0))
    scene.quad([-14, -20, 0], [0, 34, 0], [0, 0, 9], "facade_c", tile=(34.0, 9.0))
    scene.quad([14, 14, 0], [0, -34, 0], [0, 0, 8], "bricks", tile=(34.0, 8.0))
    scene.box([3.5, 7.0, 0], (2.5, 2.0, 2.6), 0.3, "posters", tile=9.0, top_tex="metal")
    scene.box([-5, 8, 0], (2.0, 0.5, 0.45), 0.0, "wood", tile=1.0)
    scene.box([6.5, 1.0, 0], (0.5, 2.0, 0.45), 0.2, "wood", tile=1.0)
    add_tree(scene, (-8.5, 4.0))
    add_tree(scene, (9.0, 9.5), 6.0)


def _arc_cameras(rng, n, centre, radius, az_range, heights, f_range, sizes, target_jitter=2.0, roll=0.07):
    cams = []
    azs = np.sort(rng.uniform(*az_range, n))
    for k in range(n):
        r = radius * rng.uniform(0.8, 1.2)
        C = np.array([centre[0] + r * np.cos(azs[k]), centre[1] + r * np.sin(azs[k]), rng.uniform(*heights)])
        tgt = np.array([centre[0], centre[1], 1.2]) + rng.normal(0, target_jitter, 3) * [1, 1, 0.3]
        size = sizes[rng.integers(len(sizes))]
        f = rng.uniform(*f_range) * max(size)
        cams.append(look_at(C, tgt, f, size, rng.normal(0, roll)))
    return cams


SIZES = [(480, 640), (450, 600), (480, 640), (640, 480), (420, 560)]


def build_square_people(rng):
    tex = _square_textures(rng)
    for name, c, st in (("shirt_a", (0.75, 0.15, 0.15), False), ("shirt_b", (0.15, 0.45, 0.3), True),
                        ("shirt_c", (0.85, 0.75, 0.2), False), ("trousers_a", (0.15, 0.2, 0.35), False),
                        ("trousers_b", (0.3, 0.25, 0.2), False), ("shirt_d", (0.5, 0.55, 0.6), True)):
        tex[name] = tex_cloth(rng, color=c, stripes=st)
    walkers = [((-4.0, -1.0), 0.35, 1.3, "shirt_a", "trousers_a", 1.78, 0.15),
               ((2.5, 4.0), -2.4, 1.1, "shirt_b", "trousers_b", 1.65, -0.1),
               ((-1.0, 6.0), -0.9, 1.4, "shirt_c", "trousers_a", 1.72, 0.12)]

    def scene_at(t):
        s = Scene(textures=tex)
        _square_static(s)
        for (x, y), head, v, sh, tr, hgt, turn in walkers:
            # walking at speed v while turning at rate `turn`: a circular arc
            hd = head + turn * t
            pos = (x + v / turn * (np.sin(hd) - np.sin(head)), y - v / turn * (np.cos(hd) - np.cos(head)))
            add_person(s, pos, hd, t, sh, tr, hgt, walking=True, phase=x)
        add_person(s, (-3.0, 9.0), -1.2, 0.0, "shirt_d", "trousers_b", 1.7, walking=False, moving=False)
        return s
    cams = _arc_cameras(rng, 8, (0, 3), 9.0, (-2.4, -0.7), (1.3, 3.6), (0.7, 1.2), SIZES)
    times = list(rng.permutation(np.linspace(0, 5.6, 8)) + rng.uniform(-0.2, 0.2, 8))
    return scene_at, cams, times


def build_courtyard_static(rng):
    tex = _square_textures(rng)
    tex["shirt_d"] = tex_cloth(rng, color=(0.5, 0.55, 0.6), stripes=True)
    tex["trousers_b"] = tex_cloth(rng, color=(0.3, 0.25, 0.2))
    tex["shirt_a"] = tex_cloth(rng, color=(0.75, 0.15, 0.15))

    def scene_at(t):
        s = Scene(textures=tex)
        _square_static(s)
        # people standing still: present, but static (they must *not* be detected)
        add_person(s, (-3.0, 9.0), -1.2, 0.0, "shirt_d", "trousers_b", 1.7, walking=False, moving=False)
        add_person(s, (1.0, 2.0), 2.0, 0.0, "shirt_a", "trousers_b", 1.8, walking=False, moving=False)
        return s
    cams = _arc_cameras(rng, 6, (0, 3), 9.0, (-2.4, -0.8), (1.3, 3.0), (0.7, 1.2), SIZES)
    return scene_at, cams, list(np.linspace(0, 5, 6))


def build_tabletop_ball(rng):
    tex = {"floor": stones(rng, (1.2, 0.16), (0.45, 0.3, 0.2), var=0.5, joint=0.05),
           "wall_a": tex_posters(rng, 1024),
           "wall_b": _graffiti(rng, 1024, stones(rng, (0.25, 0.07), (0.7, 0.45, 0.35), var=0.35, joint=0.12),
                               (6.0, 3.0)),
           "wall_c": tex_facade(rng, 1024, wall=(0.9, 0.88, 0.8), floors=3, bays=6),
           "table": tex_posters(rng, 1024, background=(0.92, 0.9, 0.82)), "wood": tex_wood(rng),
           "ball": tex_ball(rng), "book_a": tex_cloth(rng, color=(0.2, 0.3, 0.7), stripes=True),
           "book_b": tex_cloth(rng, color=(0.7, 0.2, 0.2)), "mug": tex_plain(rng, (0.9, 0.9, 0.85), var=0.1),
           "toy": tex_cloth(rng, color=(0.9, 0.6, 0.1), stripes=True)}

    def scene_at(t):
        s = Scene(textures=tex, sun=_unit(np.array([-0.3, -0.5, 0.8])))
        s.quad([-3, -3, 0], [6, 0, 0], [0, 6, 0], "floor", tile=1.0)
        s.quad([-3, 3, 0], [6, 0, 0], [0, 0, 3], "wall_a", tile=(6.0, 3.0))
        s.quad([-3, -3, 0], [0, 6, 0], [0, 0, 3], "wall_b", tile=(6.0, 3.0))
        s.quad([3, 3, 0], [0, -6, 0], [0, 0, 3], "wall_c", tile=(6.0, 3.0))
        s.box([0, 0, 0], (1.6, 0.9, 0.74), 0.0, "wood", tile=1.6, top_tex="table")
        s.box([-0.5, 0.25, 0.74], (0.24, 0.17, 0.05), 0.3, "book_a", tile=0.3)
        s.box([0.55, -0.2, 0.74], (0.2, 0.15, 0.04), -0.5, "book_b", tile=0.3)
        s.ellipsoid([0.45, 0.28, 0.80], np.eye(3), np.array([0.045, 0.045, 0.06]), "mug")
        s.box([-0.2, -0.3, 0.74], (0.08, 0.08, 0.1), 0.8, "toy", tile=0.2)
        # the ball rolls across the table, curving; its texture turns with it
        r = 0.11
        x, y = -0.6 + 0.2 * t, 0.1 * np.sin(0.7 * t)
        dist = 0.2 * t
        Rb = _rot_axis([np.sin(0.3), -np.cos(0.3), 0], dist / r) @ _rot_z(0.4)
        s.ellipsoid([x, y, 0.74 + r], Rb, np.array([r, r, r]), "ball", moving=True)
        return s
    cams = _arc_cameras(rng, 7, (0, 0), 2.1, (-2.6, -0.4), (1.05, 1.7), (0.8, 1.2), SIZES,
                        target_jitter=0.15, roll=0.06)
    cams = [look_at(c.C, np.array([0, 0, 0.8]) + rng.normal(0, 0.1, 3), c.K[0, 0], c.size, rng.normal(0, 0.06))
            for c in cams]
    times = list(rng.permutation(np.linspace(0, 6.0, 7)))
    return scene_at, cams, times


def build_plaza_many(rng):
    tex = _square_textures(rng)
    for name, c, st in (("shirt_a", (0.2, 0.25, 0.75), False), ("shirt_b", (0.8, 0.4, 0.6), True),
                        ("trousers_a", (0.15, 0.15, 0.18), False), ("trousers_b", (0.45, 0.4, 0.3), False),
                        ("cart", (0.2, 0.6, 0.3), True)):
        tex[name] = tex_cloth(rng, color=c, stripes=st)
    tex["ball"] = tex_ball(rng)

    def scene_at(t):
        s = Scene(textures=tex, sun=_unit(np.array([-0.5, 0.2, 0.8])))
        _square_static(s)
        add_person(s, (-6 + 1.2 * t, -2 + 0.3 * t), 0.25 + 0.05 * t, t, "shirt_a", "trousers_a", 1.8, phase=1.0)
        add_person(s, (5 - 0.9 * t, 5 - 0.4 * t), 3.55 - 0.08 * t, t, "shirt_b", "trousers_b", 1.6, phase=2.0)
        # a market cart pushed along a curve, turning
        s.box([-1 + 0.8 * t, 3 - 0.2 * t, 0.25], (1.2, 0.7, 0.8), 0.4 + 0.12 * t, "cart", tile=0.7,
              moving=True, top_tex="posters")
        r = 0.2
        Rb = _rot_axis([0, 1, 0], 1.5 * t / r)
        s.ellipsoid([2 - 1.5 * t, -3 + 0.2 * t, r], Rb, np.array([r, r, r]), "ball", moving=True)
        return s
    cams = _arc_cameras(rng, 12, (0, 2), 10.0, (-2.9, -0.3), (1.3, 4.5), (0.7, 1.2), SIZES)
    times = list(rng.permutation(np.linspace(0, 6.0, 12)))
    return scene_at, cams, times


# ---- scenes that provoke the failure modes of the paper's method (issue 5) ----
def _walkers(scene: Scene, t: float, walkers) -> None:
    for (x, y), head, v, sh, tr, hgt in walkers:
        add_person(scene, (x + v * np.cos(head) * t, y + v * np.sin(head) * t), head, t, sh, tr, hgt, phase=x)


def _people_textures(rng, tex: dict) -> dict:
    for name, c, st in (("shirt_a", (0.75, 0.15, 0.15), False), ("shirt_b", (0.15, 0.45, 0.3), True),
                        ("trousers_a", (0.15, 0.2, 0.35), False), ("trousers_b", (0.3, 0.25, 0.2), False)):
        tex[name] = tex_cloth(rng, color=c, stripes=st)
    tex["skin"] = tex_plain(rng, (0.85, 0.65, 0.5), var=0.1)
    return tex


def build_facade_repeat(rng):
    """Repeated texture: a facade of identical windows over periodic paving (wrong Fs fit it)."""
    bay = np.ones((256, 256, 3), np.float32) * np.array([0.78, 0.72, 0.62])
    cv2.rectangle(bay, (64, 40), (192, 200), (0.3, 0.3, 0.36), -1)
    cv2.rectangle(bay, (64, 40), (192, 200), (0.45, 0.4, 0.35), 8)
    cv2.line(bay, (128, 40), (128, 200), (0.45, 0.4, 0.35), 6)
    cv2.rectangle(bay, (56, 200), (200, 214), (0.9, 0.88, 0.8), -1)
    pattern = stones(rng, (0.5, 0.5), (0.55, 0.53, 0.5), var=0.3, joint=0.05)
    vv, uu = np.mgrid[0:256, 0:256]
    tile = pattern((uu.ravel() + 0.5) / 256 * 2.0, (vv.ravel() + 0.5) / 256 * 2.0).reshape(256, 256, 3)
    tex = _people_textures(rng, {"bays": bay, "paving": np.ascontiguousarray(tile.astype(np.float32)),
                                 "posters": tex_posters(rng, 512)})

    def scene_at(t):
        s = Scene(textures=tex)
        s.quad([-15, -10, 0], [30, 0, 0], [0, 30, 0], "paving", tile=2.0)     # repeats every 2 m
        s.quad([-15, 10, 0], [30, 0, 0], [0, 0, 12], "bays", tile=3.0)        # identical 3 m bays
        s.box([4.0, 6.0, 0], (1.5, 1.0, 2.2), 0.2, "posters", tile=4.0)
        _walkers(s, t, [((-4.0, 2.0), 0.2, 1.2, "shirt_a", "trousers_a", 1.78),
                        ((3.0, 4.0), 3.0, 1.0, "shirt_b", "trousers_b", 1.68)])
        return s
    cams = _arc_cameras(rng, 6, (0, 3), 9.0, (-2.2, -0.9), (1.4, 3.0), (0.75, 1.2), SIZES)
    return scene_at, cams, list(rng.permutation(np.linspace(0, 5, 6)))


def build_street_sideways(rng):
    """Cameras on a line at one height (horizontal epipolar lines); people walk along that line,
    so in many pairs they slide along the epipolar lines and can match themselves."""
    tex = _square_textures(rng)
    tex = _people_textures(rng, tex)

    def scene_at(t):
        s = Scene(textures=tex)
        _square_static(s)
        _walkers(s, t, [((-5.0, 5.0), 0.0, 1.3, "shirt_a", "trousers_a", 1.78),
                        ((4.0, 3.0), np.pi, 1.1, "shirt_b", "trousers_b", 1.66)])
        return s
    cams = []
    for x in np.linspace(-4.5, 4.5, 6):
        C = np.array([x + rng.normal(0, 0.2), -6.0 + rng.normal(0, 0.3), 1.6 + rng.normal(0, 0.03)])
        tgt = np.array([x * 0.3 + rng.normal(0, 0.5), 8.0, 1.6])
        size = SIZES[rng.integers(len(SIZES))]
        cams.append(look_at(C, tgt, rng.uniform(0.75, 1.1) * max(size), size, rng.normal(0, 0.02)))
    return scene_at, cams, list(rng.permutation(np.linspace(0, 5, 6)))


def build_square_wb(rng):
    """The square with strong white balance and exposure differences between cameras."""
    scene_at, cams, times = build_square_people(rng)
    return scene_at, cams[:6], times[:6]


def build_square_same_spot(rng):
    """Two spots, three shots from each (pure rotations): homography pairs within a spot,
    epipolar pairs across spots."""
    scene_at, _, _ = build_square_people(rng)
    cams = []
    for C in (np.array([-6.0, -5.0, 1.6]), np.array([5.0, -6.0, 2.2])):
        for _ in range(3):
            tgt = np.array([0.0, 4.0, 1.2]) + np.array([rng.uniform(-3, 3), 0, rng.uniform(-0.5, 0.8)])
            size = SIZES[rng.integers(len(SIZES))]
            cams.append(look_at(C, tgt, rng.uniform(0.8, 1.2) * max(size), size, rng.normal(0, 0.05)))
    return scene_at, cams, list(rng.permutation(np.linspace(0, 5, 6)))


# ---- scenes that make F hard to estimate (F precision against the true cameras, truth.py) ----
@dataclass(frozen=True)
class Stained:
    """A paving pattern under large-scale stains (wear, wet patches): texture at every distance,
    from the stones' joints nearby to the stains far away, never repeating exactly."""
    base: Stones
    stains: np.ndarray      # (n, n, 1) float32 in [0, 1], tileable
    period: float           # metres covered by one tile of the stains (not a multiple of a stone)

    def __call__(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        s = _sample(self.stains, u / self.period, v / self.period)
        return self.base(u, v) * (0.55 + 0.7 * s)


def build_arc_wide_ground(rng):
    """A wide, nearly empty square: textured paving dominates every photo, with a kiosk, a tree,
    bollards and one distant low building as the only structures off the ground plane. Ten
    cameras on an 80 degree arc, 1.2-3.5 m high, looking down at the square; two walkers. Most
    matches lie on one plane, so F is only pinned down by the few structures off it."""
    tex = _people_textures(rng, {
        "ground": Stained(stones(rng, (0.45, 0.3), (0.56, 0.52, 0.47), var=0.5, joint=0.07),
                          _fbm(rng, 512, (4, 8, 16, 32), 1), 23.7),
        "paint": tex_plain(rng, (0.92, 0.9, 0.84), var=0.15),
        "posters": tex_posters(rng, 1024), "metal": tex_plain(rng, (0.3, 0.32, 0.35), var=0.3),
        "facade": tex_facade(rng, 1024, wall=(0.78, 0.7, 0.62), floors=2, bays=9),
        "bark": tex_plain(rng, (0.35, 0.25, 0.18), var=0.5), "foliage": tex_foliage(rng)})
    # painted markings: a few long thin stripes lying on the ground (strong edges in all directions)
    stripes = [(rng.uniform(-8, 8, 2), rng.uniform(0, np.pi), rng.uniform(4, 10)) for _ in range(4)]

    def scene_at(t):
        s = Scene(textures=tex, sun=_unit(np.array([0.3, -0.6, 0.75])))
        s.quad([-30, -30, 0], [60, 0, 0], [0, 60, 0], "ground", tile=1.0)
        for (x, y), a, length in stripes:
            d, n = np.array([np.cos(a), np.sin(a), 0]), np.array([-np.sin(a), np.cos(a), 0])
            s.quad(np.array([x, y, 0.004]) - d * length / 2 - n * 0.06, d * length, n * 0.12, "paint", tile=1.0)
        s.quad([-30, 26, 0], [60, 0, 0], [0, 0, 7], "facade", tile=(30.0, 7.0))
        s.box([4.0, 5.0, 0], (2.2, 1.8, 2.5), 0.5, "posters", tile=8.0, top_tex="metal")
        for x, y in ((-3.0, -1.0), (-1.8, -1.2), (-0.6, -1.4)):
            s.box([x, y, 0], (0.18, 0.18, 0.9), 0.0, "metal", tile=1.0)
        add_tree(s, (-6.0, 6.0), 5.5)
        _walkers(s, t, [((-5.0, 1.0), 0.3, 1.3, "shirt_a", "trousers_a", 1.78),
                        ((5.0, 0.0), 2.6, 1.1, "shirt_b", "trousers_b", 1.68)])
        return s
    n = 10
    # evenly spread over the arc (with jitter), so the arc really spans about 80 degrees
    azs = np.linspace(-2.3, -0.9, n) + rng.uniform(-0.04, 0.04, n)
    cams = []
    for az in azs:
        r = 10.0 * rng.uniform(0.85, 1.2)
        C = np.array([r * np.cos(az), 1.5 + r * np.sin(az), rng.uniform(1.2, 3.5)])
        tgt = np.array([0.0, 1.5, 0.3]) + rng.normal(0, 1.5, 3) * [1, 1, 0.2]
        size = SIZES[rng.integers(len(SIZES))]
        cams.append(look_at(C, tgt, rng.uniform(0.75, 1.1) * max(size), size, rng.normal(0, 0.06)))
    return scene_at, cams, list(rng.permutation(np.linspace(0, 6, n)))


def build_low_collinear(rng):
    """Six low shots (1.0-1.3 m) taken while walking along one line, 30 degrees off the viewing
    direction, all looking roughly the same way: the camera centres are nearly collinear (all
    epipoles lie near one image line, near the image border) and the ground is seen at a grazing
    angle. Two walkers cross the square."""
    tex = _people_textures(rng, _square_textures(rng))

    def scene_at(t):
        s = Scene(textures=tex)
        _square_static(s)
        _walkers(s, t, [((-5.0, 1.0), 0.1, 1.2, "shirt_a", "trousers_a", 1.78),
                        ((4.0, 4.0), 3.0, 1.0, "shirt_b", "trousers_b", 1.66)])
        return s
    n, a = 6, 0.5
    along, across = np.array([np.sin(a), np.cos(a), 0]), np.array([np.cos(a), -np.sin(a), 0])
    cams = []
    for k in range(n):
        C = np.array([-4.5, -10.0, 0]) + along * (1.1 * k + rng.normal(0, 0.15)) + across * rng.normal(0, 0.08)
        C[2] = rng.uniform(1.0, 1.3)
        view = _rot_z(rng.normal(0, 0.06)) @ np.array([0, 1.0, 0])
        tgt = C + 15 * view + [0, 0, rng.normal(0.5, 0.4)]
        size = SIZES[rng.integers(len(SIZES))]
        cams.append(look_at(C, tgt, rng.uniform(0.75, 1.1) * max(size), size, rng.normal(0, 0.03)))
    return scene_at, cams, list(rng.permutation(np.linspace(0, 5, n)))


def build_plaza_crowd(rng, n: int = 100):
    """plaza_many's movers seen by `n` phones on a ring all around the square: a set the size of a
    crowd-sourced event, where a photo overlaps with its neighbours on the ring only (the scale
    benchmark; not bundled)."""
    scene_at, _, _ = build_plaza_many(rng)
    ring = _arc_cameras(rng, 2 * n, (0, 2), 11.0, (-np.pi, np.pi), (1.3, 4.5), (0.7, 1.2), SIZES, target_jitter=3.0)
    # nobody stands inside a tree crown or the kiosk (_square_static)
    obstacles = np.array([[-8.5, 4.0, 3.0], [9.0, 9.5, 3.2], [3.5, 7.0, 2.5]])
    free = [c for c in ring if np.all(np.hypot(*(c.C[:2, None] - obstacles[:, :2].T)) > obstacles[:, 2])]
    cams = [free[k] for k in np.sort(rng.choice(len(free), n, replace=False))]
    return scene_at, cams, list(rng.permutation(np.linspace(0, 6.0, n)))


SETS: dict[str, SetSpec] = {s.name: s for s in [
    SetSpec("square_people", "three people walking across a town square (8 cameras)", 8, 11, build_square_people),
    SetSpec("tabletop_ball", "a ball rolling across a table in a room (7 cameras)", 7, 22, build_tabletop_ball),
    SetSpec("courtyard_static", "a static square with people standing still: nothing moves (6 cameras)", 6, 33,
            build_courtyard_static),
    SetSpec("plaza_many", "two people, a pushed cart and a ball moving in a square (12 cameras)", 12, 44,
            build_plaza_many),
    SetSpec("facade_repeat", "repeated texture: identical windows and periodic paving, two walkers", 6, 55,
            build_facade_repeat),
    SetSpec("street_sideways", "cameras in a line at one height, people walking along it", 6, 66,
            build_street_sideways),
    SetSpec("square_wb", "the square with strong white balance and exposure differences", 6, 77,
            build_square_wb, look_strength=3.0),
    SetSpec("square_same_spot", "two spots, three rotated shots from each: a mixed set", 6, 88,
            build_square_same_spot),
    SetSpec("arc_wide_ground", "a wide square of textured paving seen from a wide arc, two walkers (10 cameras)",
            10, 99, build_arc_wide_ground),
    SetSpec("plaza_crowd_100", "plaza_many's movers seen by 100 phones all around the square (scale benchmark)",
            100, 123, build_plaza_crowd, bundled=False),
    SetSpec("low_collinear", "six low cameras nearly on one line, looking the same way, two walkers", 6, 111,
            build_low_collinear),
]}


def ground_truth(coverage: np.ndarray) -> np.ndarray:
    """Coverage (h, w) in [0, 1] -> uint8 mask: 255 fully covered, 0 uncovered, 128 mixed boundary."""
    gt = np.full(coverage.shape, 128, np.uint8)
    gt[coverage >= 0.999] = 255
    gt[coverage <= 0.001] = 0
    return gt


def scaled_camera(cam: Camera, scale: float) -> Camera:
    """The camera rendering an image `scale` times the size (at least 32 px a side), as write_set
    renders small test sets; the same camera when scale is 1."""
    if scale == 1.0:
        return cam
    h, w = cam.size
    hs, ws = max(32, round(h * scale)), max(32, round(w * scale))
    K = cam.K.copy()
    K[0, 0] *= ws / w
    K[1, 1] *= hs / h
    K[0, 2], K[1, 2] = (ws - 1) / 2, (hs - 1) / 2
    return Camera(K, cam.R, cam.C, (hs, ws))


def scene_and_cameras(name: str, scale: float = 1.0
                      ) -> tuple[Callable[[float], Scene], list[Camera], list[float]]:
    """Rebuild set `name` as write_set does: (scene at time t, cameras, shot times in s).

    The builder draws from a fresh rng seeded with the set's seed before anything else, so the
    scene and cameras equal those of the rendered set and its cameras.json (at the same scale).
    Raises KeyError for a name that is not in SETS.
    """
    if name not in SETS:
        raise KeyError(f"{name!r} is not a generated set (known: {', '.join(SETS)})")
    spec = SETS[name]
    scene_at, cams, times = spec.build(np.random.default_rng(spec.seed))
    return scene_at, [scaled_camera(c, scale) for c in cams], [float(t) for t in times]


def write_set(spec: SetSpec, out: Path, scale: float = 1.0) -> None:
    """Render a set to out/images/*.jpg, out/gt/*.png and out/cameras.json (atomically per file)."""
    from pipeline.cache import atomic_write_bytes

    rng = np.random.default_rng(spec.seed)
    scene_at, cams, times = spec.build(rng)      # the rng goes on to draw every camera's look
    (out / "images").mkdir(parents=True, exist_ok=True)
    (out / "gt").mkdir(parents=True, exist_ok=True)
    meta = {"name": spec.name, "description": spec.description, "generator": "crowdcam make-samples",
            "seed": spec.seed, "convention": "x = K R (X - C); pixel (0, 0) is the centre of the top-left pixel",
            "cameras": []}
    for k, (cam, t) in enumerate(zip(cams, times)):
        cam = scaled_camera(cam, scale)
        rgb_lin, cov = render(scene_at(float(t)), cam)
        look = random_look(rng, spec.look_strength)
        photo = develop(rgb_lin, look, rng)
        stem = f"cam{k:02d}"
        ok, jpg = cv2.imencode(".jpg", photo[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, look.jpeg])
        atomic_write_bytes(out / "images" / f"{stem}.jpg", jpg.tobytes())
        ok, png = cv2.imencode(".png", ground_truth(cov))
        atomic_write_bytes(out / "gt" / f"{stem}.png", png.tobytes())
        meta["cameras"].append({"stem": stem, "time_s": float(t), "K": cam.K.tolist(), "R": cam.R.tolist(),
                                "C": cam.C.tolist(), "size": list(cam.size), "look": look.__dict__})
    atomic_write_bytes(out / "cameras.json", json.dumps(meta, indent=1).encode())
