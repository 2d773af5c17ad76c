"""Cameras for the whole set (`default` preset): one reconstruction, checked, and the pairs'
geometry derived from it.

Two-view geometry cannot see its own errors away from its inliers: an F that fits matches on one
or two planes is free elsewhere and passes every two-view test. A camera registered against
tracks that three or more photos see, with its focal length estimated, fixes every pair it takes
part in. We use COLMAP's incremental mapper and bundle adjustment through `pycolmap` (maintained,
CPU only, offline) on *our* features and verified matches (features.py, support.py), so the
reconstruction and the two-view fallback see the same correspondences.

A reconstruction can be wrong as a whole (focal-depth ambiguity on planar scenes, repeated
texture), so it is checked against what the photos say before any camera is used (`_check`):
plausible focal lengths for a phone, enough reconstructed points per photo, low reprojection
error, and agreement with each pair's own verified matches. Photos that do not register, or fail a
check, keep the two-view geometry with its tests (support.py). Departure from the paper, which
uses two-view F's (BEEM) only; the `paper` preset keeps that.

Conventions: working-resolution pixels with (0, 0) at the centre of the top-left pixel (COLMAP
puts it at (0.5, 0.5); converted at the boundary). x = K R (X - C); F with x_sup^T F x_ref = 0.
"""

from __future__ import annotations

import os
import tempfile
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from .geometry import camera_parts, fundamental_from_cameras, symmetric_epipolar_distance
from .jit import LazyKernel
from .params import GeometryParams

RECONSTRUCTION = "reconstruction"


@dataclass(frozen=True)
class SetCameras:
    """The checked reconstruction of a set of n photos, at working resolution.

    registered: (n,) bool, the photo has a camera that passed the checks;
    K, R: (n, 3, 3) float64 intrinsics and world-to-camera rotation; C: (n, 3) float64 centres
    (NaN where not registered); depth_range: (n, 2) float64 near and far scene depth in front of
    each camera, from the sparse points it sees (half the 2nd, twice the 98th percentile);
    points: (M, 3) float64 sparse 3-D points; point_error: (M,) float32 mean reprojection error
    (px) in the mapper's model, before our robust refinement (see _map); point_rgb: (M, 3) uint8; obs: (O, 3) int32 rows (point, photo, keypoint index);
    pair_unc: (n, n) float64 1-sigma epipolar-line uncertainty (px, 90th percentile over the
    image) from the bundle adjustment's covariance, NaN where unknown;
    reasons: per photo "" when registered, else why not; focal_prior: (n,) EXIF focal length in
    working px or NaN; mean_reproj_px: mean reprojection error over all observations.
    """

    registered: np.ndarray
    K: np.ndarray
    R: np.ndarray
    C: np.ndarray
    depth_range: np.ndarray
    points: np.ndarray
    point_error: np.ndarray
    point_rgb: np.ndarray
    obs: np.ndarray
    pair_unc: np.ndarray
    reasons: tuple[str, ...]
    focal_prior: np.ndarray
    mean_reproj_px: float
    seconds: float

    @property
    def n_registered(self) -> int:
        return int(self.registered.sum())

    def P(self, i: int) -> np.ndarray:
        """(3, 4) projection matrix of photo i."""
        return self.K[i] @ np.hstack([self.R[i], -self.R[i] @ self.C[i][:, None]])

    def F(self, i: int, j: int) -> np.ndarray:
        """(3, 3) F with x_j^T F x_i = 0, unit norm. Each photo's P and its parts are found once
        per SetCameras (the checks ask for F of every pair of registered photos: 8 800 on a
        hundred photos)."""
        memo = self.__dict__.setdefault("_P_memo", {})
        for k in (i, j):
            if k not in memo:
                P = self.P(k)
                memo[k] = (P, camera_parts(P))
        return fundamental_from_cameras(memo[i][0], memo[j][0], memo[i][1])

    def covisible(self, i: int, j: int) -> np.ndarray:
        """(K,) int point indices observed by both photos."""
        a = self.obs[self.obs[:, 1] == i, 0]
        b = self.obs[self.obs[:, 1] == j, 0]
        return np.intersect1d(a, b)

    def view_overlap(self, i: int, j: int, size_j: tuple[int, int], X: np.ndarray | None = None) -> float:
        """Share of the sparse points photo i sees that fall inside photo j's image (in front of
        it): how much of i's scene j can speak about (occlusion aside). X: those points (N, 3),
        one per observation, when the caller has them already."""
        if X is None:
            X = self.points[self.obs[self.obs[:, 1] == i, 0]]
        if len(X) == 0:
            return 0.0
        y = (X - self.C[j]) @ self.R[j].T @ self.K[j].T
        front = y[:, 2] > 0
        uv = y[front, :2] / y[front, 2:3]
        h, w = size_j
        inside = (uv[:, 0] >= 0) & (uv[:, 0] <= w - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= h - 1)
        return float(inside.sum()) / len(X)

    def depth(self, i: int, X: np.ndarray) -> np.ndarray:
        """(N,) depth along photo i's optical axis of (N, 3) world points."""
        return (np.asarray(X) - self.C[i]) @ self.R[i][2]

    @staticmethod
    def empty(n: int, reason: str, focal_prior: np.ndarray | None = None) -> "SetCameras":
        nan = np.full((n, 3, 3), np.nan)
        return SetCameras(np.zeros(n, bool), nan, nan.copy(), np.full((n, 3), np.nan), np.full((n, 2), np.nan),
                          np.zeros((0, 3)), np.zeros(0, np.float32), np.zeros((0, 3), np.uint8),
                          np.zeros((0, 3), np.int32), np.full((n, n), np.nan), tuple([reason] * n),
                          np.full(n, np.nan) if focal_prior is None else np.asarray(focal_prior, float),
                          float("nan"), 0.0)


# ----------------------------------------------------------------------------- reconstruction
def _shift(F: np.ndarray) -> np.ndarray:
    """F in our pixel convention -> COLMAP's (pixel centres at +0.5)."""
    T = np.array([[1, 0, -0.5], [0, 1, -0.5], [0, 0, 1.0]])       # ours = T @ colmap
    return T.T @ F @ T


def _input_pairs(pairs: dict, n: int, min_matches: int) -> list[tuple[int, int, np.ndarray, bool]]:
    """(i, j, (K, 2) keypoint matches, is_homography) for the pairs whose verified matches the
    reconstruction may use. Pairs rejected as unstable or inconsistent (repeated texture) are left
    out: their matches are likely wrong."""
    out = []
    for i in range(n):
        for j in range(i + 1, n):
            g = pairs.get((i, j))
            m = None if g is None else g.inlier_idx
            if m is None or len(m) < min_matches:
                continue
            if g.reason.startswith(("unstable", "inconsistent")):
                continue
            out.append((i, j, m, g.is_homography))
    return out


def reconstruct(keypoints: list[np.ndarray], sizes: list[tuple[int, int]], pairs: dict,
                rgbs: list[np.ndarray], p: GeometryParams, focal_prior: np.ndarray | None = None,
                run_tasks: Callable[[Callable, list[tuple], Callable[[int, tuple], None]], None] | None = None
                ) -> SetCameras:
    """Cameras of the whole set from our keypoints and verified pair matches, then checked.

    keypoints: per photo (N_i, 2) float32 working pixels (the indices that PairGeometry.inlier_idx
    refers to); sizes: (h, w) per photo; pairs: PairGeometry per unordered pair (i < j);
    rgbs: (h, w, 3) uint8 per photo (point colours); focal_prior: (n,) working px or NaN.

    The mapping runs twice, from two initial focal lengths. Where the focal length is not
    determined by the photos (the focal-depth ambiguity of planar or collinear scenes), or a group
    of cameras is held to the rest by one plane, the two runs end apart: such cameras are dropped
    and such pairs get the disagreement as their uncertainty.

    run_tasks(fn, tasks, arrived): runs fn (a module-level function: `two_view_task`, `map_task`)
    on each argument tuple and calls arrived(k, result) for task k as each finishes (run.py hands
    them to its worker processes, side by side: COLMAP's two-view geometry of the matches in two
    halves, then the two mapping runs; the first run's checks, seconds on one core, go on while the
    other run maps); default: one after the other, here.
    """
    import dataclasses

    t0 = time.perf_counter()
    n = len(keypoints)
    prior = np.full(n, np.nan) if focal_prior is None else np.asarray(focal_prior, float)
    links = _input_pairs(pairs, n, p.recon_min_matches)
    if n < 3 or len(links) < 2:
        return SetCameras.empty(n, "the set has too few overlapping photos for a reconstruction", prior)
    # Side by side in processes, not threads: in two threads of one process (pycolmap lets go of
    # the GIL) the runs drew from one random generator and their cameras came out up to 3e-4 apart
    # from those of runs one at a time; in a process each, they are the same bit for bit.
    run = run_tasks or _run_here
    # COLMAP's two-view geometry of every linked pair, once for both runs: it does not depend on the
    # initial focal length (without a focal prior on both photos it is the uncalibrated estimate,
    # which reads no focal; with priors, both runs start from them). Each run made its own before,
    # the same bit for bit (a hundred photos: 6 s of each run's 44).
    halves = max(1, len(p.recon_focal_guesses))
    two_view: list = [None] * len(links)

    def got_two_view(k: int, result: list) -> None:
        two_view[k::halves] = result
    run(two_view_task, [(keypoints, sizes, links[k::halves], prior, p.recon_focal_guesses[0])
                        for k in range(halves)], got_two_view)
    tasks = [(keypoints, sizes, links, two_view, p, prior, guess) for guess in p.recon_focal_guesses]
    runs: dict[int, tuple] = {}
    failures: list[str] = []

    def arrived(k: int, result: tuple) -> None:
        failure, model, ids, n_models = result
        if failure:                              # a failed reconstruction is a fallback, not a crash
            failures.append(failure)
        if failures:
            return
        rec = _model_from_bytes(model)
        if rec is None:
            runs[k] = (None,)
        elif k == 0:
            runs[k] = (rec, ids, *_checked(rec, ids, n_models, keypoints, sizes, pairs, rgbs, p, prior))
        else:
            runs[k] = (_extract(rec, ids, n, rgbs, keypoints, prior),)
    run(map_task, tasks, arrived)
    if failures:
        return SetCameras.empty(n, f"the reconstruction failed ({failures[0]})", prior)
    if runs[0][0] is None:
        return SetCameras.empty(n, "no initial pair of photos could be reconstructed", prior)
    _, _, cams, wanted, samples, unc = runs[0]
    for k in range(1, len(tasks)):
        alt = runs[k][0]
        if alt is None:
            continue
        cams, spread = _compare_runs(cams, alt, sizes, p, wanted, samples)
        samples = None                    # the cameras kept changed: a further run's comparison samples anew
        unc = np.fmax(unc, spread)
    return dataclasses.replace(cams, pair_unc=unc, seconds=time.perf_counter() - t0)


def _checked(rec, ids: list[int], n_models: int, keypoints, sizes, pairs: dict, rgbs, p: GeometryParams,
             prior: np.ndarray) -> tuple:
    """The first run's cameras checked (_check), the pairs that want their lines' uncertainty,
    the scene's samples and that uncertainty: (cams, wanted (n, n) bool, samples, unc (n, n))."""
    cams = _check(_extract(rec, ids, len(keypoints), rgbs, keypoints, prior), pairs, sizes, p, n_models)
    # the lines' uncertainty only for pairs that can use it: a pair whose cameras see too little of
    # the same scene is rejected whatever its lines (on a hundred photos 2 400 of 8 700 pairs pass;
    # the others' NaN reads "not estimated")
    wanted = _Covisibility(cams, sizes, p).pairs()
    for (i, j), g in pairs.items():          # a homography pair of registered photos is swept when its lines are certain
        if g.is_homography:
            wanted[i, j] = wanted[j, i] = True
    samples = _SceneSamples(cams, sizes)          # the scene's points per pair, for both measures
    return cams, wanted, samples, _pair_uncertainty(rec, ids, cams, sizes, wanted, samples)


def _initial_cameras(sizes, prior: np.ndarray, focal_guess: float) -> list:
    """pycolmap cameras per photo: its EXIF focal length as a prior, else `focal_guess` x the longer side."""
    import pycolmap
    cameras = []
    for k, (h, w) in enumerate(sizes):
        f0 = prior[k] if np.isfinite(prior[k]) else focal_guess * max(h, w)
        cam = pycolmap.Camera(model="SIMPLE_PINHOLE", width=w, height=h, params=[f0, w / 2, h / 2])
        cam.has_prior_focal_length = bool(np.isfinite(prior[k]))
        cameras.append(cam)
    return cameras


def two_view_task(keypoints, sizes, links, prior: np.ndarray, focal_guess: float) -> list:
    """COLMAP's own two-view geometry (pycolmap.TwoViewGeometry) of each link's verified matches:
    its configuration (calibrated, planar, panoramic...) and relative pose choose the mapper's
    initial pair and guide registration (written without them, the mapper registered far fewer
    photos, with focal errors of 100 %). A task for a worker process (the objects pickle whole)."""
    import pycolmap
    cameras = _initial_cameras(sizes, prior, focal_guess)
    verify = pycolmap.TwoViewGeometryOptions()
    verify.ransac.random_seed = 0
    return [pycolmap.estimate_two_view_geometry(cameras[i], keypoints[i].astype(np.float64) + 0.5, cameras[j],
                                                keypoints[j].astype(np.float64) + 0.5,
                                                np.ascontiguousarray(m, np.uint32), verify)
            for i, j, m, _ in links]


def map_task(keypoints, sizes, links, two_view, p: GeometryParams, prior: np.ndarray, focal_guess: float
             ) -> tuple[str, dict[str, bytes] | None, list[int], int]:
    """One mapping run (`_map`) as a task for a worker process: (failure or "", the model's COLMAP
    binary files or None, image ids per photo, number of models). The files hold the model's
    doubles as they are, so the model read back is the one the worker made, bit for bit."""
    try:
        rec, ids, n_models = _map(keypoints, sizes, links, two_view, p, prior, focal_guess)
    except Exception as e:
        return f"{type(e).__name__}: {e}", None, [], 0
    if rec is None:
        return "", None, ids, n_models
    with tempfile.TemporaryDirectory(prefix="crowdcam-model-") as tmp:
        rec.write_binary(tmp)
        files = {name: open(os.path.join(tmp, name), "rb").read() for name in sorted(os.listdir(tmp))}
    return "", files, ids, n_models


def _run_here(fn: Callable, tasks: list[tuple], arrived: Callable[[int, tuple], None]) -> None:
    for k, t in enumerate(tasks):
        arrived(k, fn(*t))


def _model_from_bytes(files: dict[str, bytes] | None):
    if files is None:
        return None
    import pycolmap
    with tempfile.TemporaryDirectory(prefix="crowdcam-model-") as tmp:
        for name, data in files.items():
            with open(os.path.join(tmp, name), "wb") as f:
                f.write(data)
        return pycolmap.Reconstruction(tmp)


def _map(keypoints, sizes, links, two_view, p: GeometryParams, prior: np.ndarray, focal_guess: float):
    """One COLMAP incremental mapping of our matches and their two-view geometries (two_view_task,
    one per link), then the robust refinement.

    Returns (the largest pycolmap.Reconstruction or None, image ids per photo, number of models).
    Photos without an EXIF prior start at `focal_guess` x the longer side."""
    import pycolmap

    # COLMAP's log is not for our users: FATAL only (3), as its ERROR lines ("Failed to create any
    # sparse model") reached the terminal beside our own one-line warning of the same thing
    pycolmap.logging.minloglevel = int(os.environ.get("CROWDCAM_COLMAP_LOG", 3))
    with tempfile.TemporaryDirectory(prefix="crowdcam-sfm-") as tmp:
        db_path = os.path.join(tmp, "database.db")
        db = pycolmap.Database.open(db_path)
        ids = []
        for k, (cam, kp) in enumerate(zip(_initial_cameras(sizes, prior, focal_guess), keypoints)):
            ids.append(db.write_image(pycolmap.Image(name=f"{k:05d}", camera_id=db.write_camera(cam))))
            db.write_keypoints(ids[-1], np.asarray(kp, np.float32).reshape(-1, 2) + 0.5)
        for (i, j, m, _), tvg in zip(links, two_view):
            db.write_matches(ids[i], ids[j], np.ascontiguousarray(m, np.uint32))
            if len(tvg.inlier_matches) >= p.recon_min_matches:
                db.write_two_view_geometry(ids[i], ids[j], tvg)
        db.close()
        opts = pycolmap.IncrementalPipelineOptions()
        # Sets shot from a few spots have small triangulation angles between spots: COLMAP's
        # default initial pair (16 deg, 100 inliers) then finds none (EVIDENCE_NOTES).
        opts.mapper.init_min_tri_angle = p.recon_init_tri_angle
        opts.mapper.init_min_num_inliers = p.recon_init_inliers
        opts.triangulation.ignore_two_view_tracks = False
        opts.triangulation.random_seed = 0
        opts.min_model_size = 3
        opts.extract_colors = False
        opts.num_threads = 1                    # deterministic; the mapper takes about a second here
        opts.random_seed = 0
        opts.mapper.random_seed = 0
        opts.max_runtime_seconds = p.recon_max_seconds
        # a large set's bundle adjustments, lighter (GeometryParams.recon_light_ba_above): the global
        # ones without redundant points (those whose photos the others cover well enough), and the
        # robust refinement below to Ceres' own function tolerance; most of its mapping time went there
        large = len(keypoints) > p.recon_light_ba_above
        opts.mapper.ba_global_ignore_redundant_points3D = large
        if large:   # and each global one stops when an iteration gains less than this share of the cost
            opts.ba_global_function_tolerance = p.recon_light_ba_tolerance
        pycolmap.set_random_seed(0)
        models = pycolmap.incremental_mapping(db_path, tmp, os.path.join(tmp, "out"), opts)
    if not models:
        return None, ids, 0
    rec = max(models.values(), key=lambda r: r.num_reg_images())
    mapper_error = {pid: pt.error for pid, pt in rec.points3D.items()}
    _robust_refinement(rec, p.recon_max_reproj_px, function_tolerance=1e-6 if large else 0.0)
    # Each point keeps the mapper's error (before the refinement), which scales the lines'
    # uncertainty (_pair_uncertainty) and with which its limits were measured. COLMAP's filter in
    # the refinement leaves the refined model's, about 15 % smaller: with them arc_wide_ground
    # admitted 4 more pairs with wrong lines (F precision 89 -> 80 %, Jaccard 0.40 -> 0.38).
    for pid, pt in rec.points3D.items():
        pt.error = mapper_error[pid]
    return rec, ids, len(models)


class _SceneSamples:
    """Points of photo i at the depths of its scene (5 percentiles of its sparse points) on a grid,
    and where photo j's camera sees them: samples(i, j) -> (x_i (N, 2), y_j (N, 2)) float64, y_j
    inside photo j. The part that depends on i alone (its points' depths, the grid lifted into the
    world) is computed once per photo: the checks ask for every pair of registered photos (8 800
    on a hundred photos, where finding each photo's points anew cost 12 s)."""

    def __init__(self, cams: "SetCameras", sizes):
        self.cams, self.sizes, self._lifted, self._pairs = cams, sizes, {}, {}

    def _lift(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """(grid x_i (G, 2) repeated per depth (5G, 2), the world points (5G, 3)), empty without points."""
        if i not in self._lifted:
            cams = self.cams
            z = cams.depth(i, cams.points[cams.obs[cams.obs[:, 1] == i, 0]])
            z = z[z > 0]
            if len(z) < 5:
                self._lifted[i] = (np.zeros((0, 2)), np.zeros((0, 3)))
            else:
                zs = np.percentile(z, [5, 25, 50, 75, 95])
                h, w = self.sizes[i]
                gx, gy = np.meshgrid(np.linspace(0, w - 1, 12), np.linspace(0, h - 1, 9))
                x = np.column_stack([gx.ravel(), gy.ravel(), np.ones(gx.size)])
                Xc = ((x @ np.linalg.inv(cams.K[i]).T)[None] * zs[:, None, None]).reshape(-1, 3)
                self._lifted[i] = (np.tile(x[:, :2], (len(zs), 1)), Xc @ cams.R[i] + cams.C[i])
        return self._lifted[i]

    def __call__(self, i: int, j: int) -> tuple[np.ndarray, np.ndarray]:
        if (i, j) not in self._pairs:        # kept: the uncertainty and the runs' comparison ask for the same pairs
            self._pairs[(i, j)] = self._project(i, j)
        return self._pairs[(i, j)]

    def _project(self, i: int, j: int) -> tuple[np.ndarray, np.ndarray]:
        x, X = self._lift(i)
        if not len(x):
            return x, np.zeros((0, 2))
        cams = self.cams
        y = (X - cams.C[j]) @ cams.R[j].T @ cams.K[j].T
        ok = y[:, 2] > 1e-9
        y = y[ok, :2] / y[ok, 2:3]
        xi = x[ok]
        hj, wj = self.sizes[j]
        inside = (y[:, 0] >= 0) & (y[:, 0] <= wj - 1) & (y[:, 1] >= 0) & (y[:, 1] <= hj - 1)
        return xi[inside], y[inside]


class _Covisibility:
    """Whether two registered photos see enough of the same scene to be a reconstruction pair
    (apply_reconstruction's first test): `recon_min_covisible` points seen by both, or else
    `recon_min_overlap` of each photo's points in view of the other. Each photo's observations are
    found once: the test is asked for every pair of registered photos (8 700 on a hundred photos).
    __call__(i, j) -> (common point indices (K,), overlap, enough)."""

    def __init__(self, cams: "SetCameras", sizes, p: GeometryParams):
        n = len(cams.registered)
        order = np.argsort(cams.obs[:, 1], kind="stable")
        bounds = np.searchsorted(cams.obs[order, 1], np.arange(n + 1))
        self.rows = [order[bounds[k]:bounds[k + 1]] for k in range(n)]      # each photo's observations
        self.seen_by = [np.unique(cams.obs[r, 0]) for r in self.rows]
        self.observed = [cams.points[cams.obs[r, 0]] for r in self.rows]   # one per observation
        self.cams, self.sizes, self.p = cams, sizes, p

    def __call__(self, i: int, j: int) -> tuple[np.ndarray, float, bool]:
        p, cams = self.p, self.cams
        common = np.intersect1d(self.seen_by[i], self.seen_by[j], assume_unique=True)   # cams.covisible(i, j)
        if len(common) >= p.recon_min_covisible:
            return common, 1.0, True
        # the share of each photo's scene in view of the other matters only with few common points
        overlap = min(cams.view_overlap(i, j, self.sizes[j], self.observed[i]),
                      cams.view_overlap(j, i, self.sizes[i], self.observed[j]))
        return common, overlap, overlap >= p.recon_min_overlap

    def pairs(self) -> np.ndarray:
        """(n, n) bool: registered pairs that pass the test (symmetric)."""
        n = len(self.cams.registered)
        out = np.zeros((n, n), bool)
        reg = np.nonzero(self.cams.registered)[0]
        for a, i in enumerate(reg):
            for j in reg[a + 1:]:
                out[i, j] = out[j, i] = self(i, j)[2]
        return out


def _compare_runs(cams: "SetCameras", alt: "SetCameras", sizes, p: GeometryParams, wanted: np.ndarray | None = None,
                  samples: "_SceneSamples | None" = None):
    """Drop the cameras whose focal length the second run puts elsewhere; (n, n) disagreement of
    the pairs' epipolar lines between the runs (px, 90th percentile at the scene's depths), for
    the pairs `wanted` ((n, n) bool; default all), NaN elsewhere. samples: _SceneSamples(cams, sizes)
    when the caller has it."""
    from .geometry import epipolar_lines
    n = len(cams.registered)
    reg = cams.registered.copy()
    reasons = list(cams.reasons)
    for k in np.nonzero(reg)[0]:
        if not alt.registered[k]:
            continue
        ratio = alt.K[k][0, 0] / cams.K[k][0, 0]
        if abs(np.log(ratio)) > np.log(1 + p.recon_focal_agree):
            reg[k], reasons[k] = False, (f"its focal length is not determined by the photos (two reconstructions "
                                         f"from different starting values differ by {abs(ratio - 1):.0%})")
    spread = np.full((n, n), np.nan)
    samples = _SceneSamples(cams, sizes) if samples is None else samples
    for i in np.nonzero(reg)[0]:
        for j in np.nonzero(reg)[0]:
            if i == j or not (alt.registered[i] and alt.registered[j]) or (wanted is not None and not wanted[i, j]):
                continue
            xi, yj = samples(i, j)
            if len(xi):
                lines = epipolar_lines(alt.F(i, j), xi)
                spread[i, j] = float(np.percentile(np.abs(np.sum(lines[:, :2] * yj, axis=1) + lines[:, 2]), 90))
    return _keep(cams, reg, reasons, p), spread


def _keep(cams: SetCameras, reg: np.ndarray, reasons: list[str], p: GeometryParams) -> SetCameras:
    """cams with only the photos `reg` registered (the others' cameras NaN, with their reasons);
    none when fewer than `recon_min_registered` are left: a model of three cameras cannot check
    itself (each camera answers to two others only)."""
    import dataclasses
    if reg.sum() < p.recon_min_registered:
        why = f"fewer than {p.recon_min_registered} photos passed the reconstruction's checks"
        reasons = [r or why for r in reasons]
        reg = np.zeros_like(reg)
    nan3 = np.full((3, 3), np.nan)
    K, R, C = cams.K.copy(), cams.R.copy(), cams.C.copy()
    K[~reg], R[~reg], C[~reg] = nan3, nan3, np.nan
    return dataclasses.replace(cams, registered=reg, K=K, R=R, C=C, reasons=tuple(reasons),
                               depth_range=np.where(reg[:, None], cams.depth_range, np.nan))


def _robust_refinement(rec, max_px: float, rounds: int = 2, function_tolerance: float = 0.0) -> None:
    """A final bundle adjustment with a robust (Cauchy) loss, dropping observations that still
    reproject farther than `max_px`, twice. COLMAP's own bundle adjustments use a plain squared
    loss; a few per cent of wrong matches that agree across views (repeated texture) then pull the
    focal lengths by several per cent, measured on the rendered sets (square_people: focal errors
    of up to 4 % fell below 1 % for all but one photo). function_tolerance: Ceres stops when an
    iteration lowers the cost by less than this share (COLMAP's 0: only the gradient or 100
    iterations stop it; Ceres' own default 1e-6 halves the time on a hundred photos, the lines
    within 0.03 px of the 0's)."""
    import pycolmap

    opts = pycolmap.BundleAdjustmentOptions()
    opts.print_summary = False
    opts.ceres.loss_function_type = pycolmap.LossFunctionType.CAUCHY
    opts.ceres.loss_function_scale = 1.0
    opts.ceres.solver_options.num_threads = 1
    opts.ceres.solver_options.function_tolerance = function_tolerance
    for _ in range(rounds):
        config = pycolmap.BundleAdjustmentConfig()
        for iid in rec.reg_image_ids():
            config.add_image(iid)
        config.fix_gauge(pycolmap.BundleAdjustmentGauge.THREE_POINTS)
        # the adjuster itself, not pycolmap.bundle_adjustment, which prints a heading whatever the log level
        pycolmap.create_default_bundle_adjuster(opts, config, rec).solve()
        # observations farther than max_px (or behind their camera) go; a point left with fewer than
        # two goes whole. COLMAP's own filter: our loop over the observations in Python did the same,
        # to the same cameras bit for bit, in 1.4 s more per run on a hundred photos
        far = pycolmap.ObservationManager(rec).filter_points3D_with_large_reprojection_error(
            max_px, set(rec.point3D_ids()))
        if not far:
            break


def _extract(rec, ids: list[int], n: int, rgbs, keypoints, prior) -> SetCameras:
    """Our arrays from a pycolmap.Reconstruction (image ids -> photo indices, pixel convention)."""
    index = {iid: k for k, iid in enumerate(ids)}
    K = np.full((n, 3, 3), np.nan)
    R = np.full((n, 3, 3), np.nan)
    C = np.full((n, 3), np.nan)
    reg = np.zeros(n, bool)
    for iid in rec.reg_image_ids():
        k = index[iid]
        im = rec.image(iid)
        f, cx, cy = im.camera.params[:3]
        K[k] = [[f, 0, cx - 0.5], [0, f, cy - 0.5], [0, 0, 1]]
        pose = im.cam_from_world()
        R[k] = pose.rotation.matrix()
        C[k] = -R[k].T @ pose.translation
        reg[k] = True
    pids = sorted(rec.point3D_ids())
    pts = np.array([rec.point3D(q).xyz for q in pids], np.float64).reshape(-1, 3)
    err = np.array([rec.point3D(q).error for q in pids], np.float32)
    obs = [(a, index[e.image_id], e.point2D_idx) for a, q in enumerate(pids) for e in rec.point3D(q).track.elements]
    obs = np.array(obs, np.int32).reshape(-1, 3)
    rgb = np.zeros((len(pids), 3), np.uint8)
    if len(obs):                                   # colour of each point in its first observation
        first = obs[np.unique(obs[:, 0], return_index=True)[1]]
        for k in np.unique(first[:, 1]):           # a photo at a time (a loop over 17 000 points took 0.7 s)
            a, kp = first[first[:, 1] == k][:, [0, 2]].T
            x, y = np.round(keypoints[k][kp]).astype(int).T
            img = rgbs[k]
            rgb[a] = img[np.clip(y, 0, img.shape[0] - 1), np.clip(x, 0, img.shape[1] - 1)]
    reasons = tuple("" if reg[k] else "not registered by the reconstruction" for k in range(n))
    mean_err = float(np.mean(err)) if len(err) else float("nan")
    cams = SetCameras(reg, K, R, C, np.full((n, 2), np.nan), pts, err, rgb, obs, np.full((n, n), np.nan),
                      reasons, prior, mean_err, 0.0)
    return _with_depth_ranges(cams)


def _with_depth_ranges(cams: SetCameras) -> SetCameras:
    import dataclasses
    rng = np.full((len(cams.registered), 2), np.nan)
    for k in np.nonzero(cams.registered)[0]:
        z = cams.depth(k, cams.points[cams.obs[cams.obs[:, 1] == k, 0]])
        z = z[z > 0]
        if len(z) >= 5:
            rng[k] = 0.5 * np.percentile(z, 2), 2.0 * np.percentile(z, 98)
    return dataclasses.replace(cams, depth_range=rng)


def _fits_matches(F: np.ndarray, g, max_px: float) -> bool:
    """F (3, 3) fits the pair's own verified matches: their median symmetric epipolar distance is
    at most max_px (a two-view pair's inliers, PairGeometry)."""
    if g.inliers_ref is None or len(g.inliers_ref) == 0:
        return False
    return bool(np.median(symmetric_epipolar_distance(F, g.inliers_ref, g.inliers_sup)) <= max_px)


def _takes_over(F: np.ndarray, g, side: int, p: GeometryParams) -> bool:
    """recon_over_two_view: the cameras' F (3, 3) replaces pair g's passing two-view F although the
    cameras' lines are too uncertain by the estimate, because it fits the pair's own matches and the
    two-view lines are certain themselves (within the gate's limit, two_view_max_uncertainty_frac x
    the image side `side`; without that gate, never: every passing pair took in arc's wrong cameras)."""
    limit = p.two_view_max_uncertainty_frac * side
    return bool(p.recon_over_two_view and g.ok and limit > 0 and g.uncertainty_px <= limit
                and _fits_matches(F, g, p.recon_agree_px))


def _check(cams: SetCameras, pairs: dict, sizes, p: GeometryParams, n_models: int) -> SetCameras:
    """Unregister the photos whose camera the photos themselves contradict (see module doc)."""
    n = len(cams.registered)
    reg = cams.registered.copy()
    reasons = list(cams.reasons)
    if n_models > 1:
        for k in range(n):
            if not reg[k] and reasons[k].startswith("not registered"):
                reasons[k] = "not registered (its photos formed a separate, smaller reconstruction or none)"
    for k in np.nonzero(reg)[0]:
        side = max(sizes[k])
        f = cams.K[k][0, 0]
        mine = cams.obs[:, 1] == k
        if not p.recon_focal_range[0] <= f / side <= p.recon_focal_range[1]:
            reg[k], reasons[k] = False, (f"implausible focal length for a phone ({f / side:.2f} x the image side)")
        elif mine.sum() < p.recon_min_points:
            reg[k], reasons[k] = False, f"sees only {int(mine.sum())} reconstructed points (< {p.recon_min_points})"
        elif np.isfinite(cams.focal_prior[k]) and abs(np.log(f / cams.focal_prior[k])) > np.log(1.5):
            reg[k], reasons[k] = False, (f"focal length {f:.0f} px is far from its EXIF value "
                                         f"{cams.focal_prior[k]:.0f} px")
    # Agreement with each pair's own verified matches (they are what the photos say).
    bad, evaluated = np.zeros(n, int), np.zeros(n, int)
    for (i, j), g in pairs.items():
        if i >= j or not (reg[i] and reg[j]) or g.inlier_idx is None or len(g.inlier_idx) < p.recon_min_matches:
            continue
        if g.reason.startswith(("unstable", "inconsistent")):
            continue
        off = not _fits_matches(cams.F(i, j), g, p.recon_agree_px)
        for k in (i, j):
            evaluated[k] += 1
            bad[k] += off
    for k in np.nonzero(reg)[0]:
        if evaluated[k] >= 2 and bad[k] > evaluated[k] / 2:
            reg[k], reasons[k] = False, (f"its camera disagrees with its own matches ({bad[k]} of {evaluated[k]} "
                                         f"pairs off by more than {p.recon_agree_px:g} px)")
    return _keep(cams, reg, reasons, p)


# ----------------------------------------------------------------------------- uncertainty
def line_uncertainty(Ki, Kj, R_rel, t_rel, cov6, x_i: np.ndarray, y_j: np.ndarray, samples: int = 32,
                     seed: int = 0) -> float:
    """1-sigma epipolar-line uncertainty in photo j (px), 90th percentile over the given points.

    The relative pose X_j = R_rel X_i + t_rel has covariance cov6 ((6, 6), rotation tangent then
    translation). x_i (N, 2) are points of photo i and y_j (N, 2) where the nominal cameras see them
    in photo j (at the scene's depths, `_SceneSamples`); their distance to the epipolar lines of
    poses drawn from the covariance is the lines' spread where it matters: all over the image, not
    only at the matches. The poses are drawn all at once (the same draws as one at a time); their
    lines and distances come from one compiled pass (`_line_rms_numba`): the same figures as
    numpy's to float rounding, 1.1 -> 0.23 ms a call at 300 points (numpy's forty-odd small steps
    on (32, N, 3) temporaries were most of it; the checks of a hundred photos ask 3,800 times).
    """
    try:
        L = np.linalg.cholesky(cov6 + 1e-18 * np.eye(6))
    except np.linalg.LinAlgError:
        return float("nan")
    rng = np.random.default_rng(seed)
    dlt = rng.standard_normal((samples, 6)) @ L.T                                    # (S, 6)
    rms = _line_rms_kernel(np.ascontiguousarray(np.linalg.inv(Kj).T), np.ascontiguousarray(R_rel @ np.linalg.inv(Ki)),
                           np.asarray(t_rel, np.float64), dlt, np.ascontiguousarray(x_i, np.float64),
                           np.ascontiguousarray(y_j, np.float64))
    return float(np.percentile(rms, 90))


def _line_rms_numba():
    """Per point, the RMS over the drawn poses of its distance to their epipolar lines (numba).

    Kj_inv_T, M = R_rel Ki^-1: (3, 3); t: (3,); dlt: (S, 6) pose draws (rotation vector, then
    translation); x, y: (N, 2). For each draw F = Kj^-T [t + dt]_x Rodrigues(dw) M (HZ 9.6, the
    draw's rotation applied after the nominal one), the line F (x, 1) and y's distance to it.
    Returns (N,) float64. The 3 x 3 products are written out (numba's @ needs SciPy's BLAS)."""
    import numba

    @numba.njit(cache=True, nogil=True)
    def kernel(Kj_inv_T, M, t, dlt, x, y):
        S, N = dlt.shape[0], x.shape[0]
        acc = np.zeros(N)
        R = np.empty((3, 3))
        T = np.empty((3, 3))
        P = np.empty((3, 3))
        F = np.empty((3, 3))
        for s in range(S):
            w0, w1, w2 = dlt[s, 0], dlt[s, 1], dlt[s, 2]
            ang = np.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
            if ang < 1e-12:                  # first order: R = I + [w]_x
                sa, ca = 1.0, 0.0
            else:
                w0, w1, w2 = w0 / ang, w1 / ang, w2 / ang
                sa, ca = np.sin(ang), 1.0 - np.cos(ang)
            # R = I + sin(a) [k]_x + (1 - cos(a)) [k]_x^2, [k]_x^2 = k k^T - |k|^2 I
            kk = w0 * w0 + w1 * w1 + w2 * w2
            R[0, 0] = 1.0 + ca * (w0 * w0 - kk)
            R[0, 1] = -sa * w2 + ca * w0 * w1
            R[0, 2] = sa * w1 + ca * w0 * w2
            R[1, 0] = sa * w2 + ca * w1 * w0
            R[1, 1] = 1.0 + ca * (w1 * w1 - kk)
            R[1, 2] = -sa * w0 + ca * w1 * w2
            R[2, 0] = -sa * w1 + ca * w2 * w0
            R[2, 1] = sa * w0 + ca * w2 * w1
            R[2, 2] = 1.0 + ca * (w2 * w2 - kk)
            t0, t1, t2 = t[0] + dlt[s, 3], t[1] + dlt[s, 4], t[2] + dlt[s, 5]
            T[0, 0], T[0, 1], T[0, 2] = 0.0, -t2, t1
            T[1, 0], T[1, 1], T[1, 2] = t2, 0.0, -t0
            T[2, 0], T[2, 1], T[2, 2] = -t1, t0, 0.0
            for r in range(3):               # P = Kj^-T T
                for c in range(3):
                    P[r, c] = Kj_inv_T[r, 0] * T[0, c] + Kj_inv_T[r, 1] * T[1, c] + Kj_inv_T[r, 2] * T[2, c]
            for r in range(3):               # F = P R
                for c in range(3):
                    F[r, c] = P[r, 0] * R[0, c] + P[r, 1] * R[1, c] + P[r, 2] * R[2, c]
            for r in range(3):               # P = F M
                for c in range(3):
                    P[r, c] = F[r, 0] * M[0, c] + F[r, 1] * M[1, c] + F[r, 2] * M[2, c]
            for n in range(N):
                l0 = P[0, 0] * x[n, 0] + P[0, 1] * x[n, 1] + P[0, 2]
                l1 = P[1, 0] * x[n, 0] + P[1, 1] * x[n, 1] + P[1, 2]
                l2 = P[2, 0] * x[n, 0] + P[2, 1] * x[n, 1] + P[2, 2]
                d = (l0 * y[n, 0] + l1 * y[n, 1] + l2) / np.sqrt(l0 * l0 + l1 * l1)
                acc[n] += d * d
        return np.sqrt(acc / S)
    return kernel


_line_rms_kernel = LazyKernel(_line_rms_numba)


def _pair_uncertainty(rec, ids: list[int], cams: SetCameras, sizes, wanted: np.ndarray | None = None,
                      samples: "_SceneSamples | None" = None) -> np.ndarray:
    """(n, n) line uncertainty for every pair of registered photos, or only those `wanted`
    ((n, n) bool), NaN elsewhere and when not estimable. samples: _SceneSamples(cams, sizes) when
    the caller has it."""
    import pycolmap

    n = len(cams.registered)
    out = np.full((n, n), np.nan)
    reg = np.nonzero(cams.registered)[0]
    if len(reg) < 2:
        return out
    try:
        config = pycolmap.BundleAdjustmentConfig()
        for k in reg:
            config.add_image(ids[k])
        config.fix_gauge(pycolmap.BundleAdjustmentGauge.THREE_POINTS)
        ba = pycolmap.create_default_ceres_bundle_adjuster(pycolmap.BundleAdjustmentOptions(), config, rec)
        cov = pycolmap.estimate_ba_covariance(pycolmap.BACovarianceOptions(), rec, ba)
    except Exception:
        cov = None
    if cov is None:
        return out
    # The covariance assumes 1 px image noise; scale it to the residuals we actually have.
    sigma2 = float(np.mean(cams.point_error.astype(np.float64) ** 2)) if len(cams.point_error) else 1.0
    samples = _SceneSamples(cams, sizes) if samples is None else samples
    for i in reg:
        pi = rec.image(ids[i]).cam_from_world()
        for j in reg:
            if i == j or (wanted is not None and not wanted[i, j]):
                continue
            pj = rec.image(ids[j]).cam_from_world()
            c = cov.get_cam2_cov_from_cam1(ids[i], pi, ids[j], pj)
            if c is None:
                continue
            rel = pj * pi.inverse()
            R_rel, t_rel = rel.rotation.matrix(), np.asarray(rel.translation)
            xi, yj = samples(i, j)
            if len(xi):
                # to a micro-pixel: the covariance's last bits follow where its blocks lie in memory
                # (a model read back from the worker's files: 1e-12 px from run to run)
                out[i, j] = round(line_uncertainty(cams.K[i], cams.K[j], R_rel, t_rel, np.asarray(c) * sigma2, xi, yj,
                                                   seed=int(i * n + j)), 6)
    return out


# ----------------------------------------------------------------------------- pairs
def apply_reconstruction(pairs: dict, cams: SetCameras, sizes, keypoints: list[np.ndarray],
                         p: GeometryParams) -> dict:
    """Pair geometry (both orders) with F from the cameras wherever both photos are registered.

    A homography pair (shots from one spot) stays a homography pair. Other pairs of registered
    photos become `reconstruction` pairs when their cameras see enough common points, even when
    the two-view tests rejected them (a plane seen from two places is degenerate for two views,
    not for cameras known from the whole set). Where the cameras' lines are too uncertain by the
    estimate, a pair whose own two-view F passed keeps it, unless `recon_over_two_view`: then the
    cameras' F is taken where it fits the pair's matches and the two-view lines are certain (on
    plaza_many the estimate was 3-10x the cameras' true error, and 2 of 7 such two-view F's were
    12-22 px off at the 90th percentile). Pairs with an unregistered photo keep the two-view result.
    """
    import dataclasses

    from .support import OK, REJECTED
    out = dict(pairs)
    n = len(cams.registered)
    covisibility = _Covisibility(cams, sizes, p)
    rows, seen_by = covisibility.rows, covisibility.seen_by
    for i in range(n):
        for j in range(i + 1, n):
            g = pairs[(i, j)]
            if not (cams.registered[i] and cams.registered[j]) or g.is_homography:
                continue
            common, overlap, enough = covisibility(i, j)
            both = (cams.pair_unc[i, j], cams.pair_unc[j, i])
            unc = float(max(u for u in both if not np.isnan(u))) if np.isfinite(both).any() else float("nan")
            baseline = float(np.linalg.norm(cams.C[i] - cams.C[j]))
            seen = cams.points[common] if len(common) else cams.points[seen_by[i]]
            depth = float(np.median(cams.depth(i, seen))) if len(seen) else float("nan")
            why = None
            if not enough:
                why = (f"the cameras see little of the same scene ({len(common)} common points, {overlap:.0%} of "
                       "the scene in view of both)")
            elif not baseline > p.recon_min_baseline * depth:
                why = (f"no baseline: the cameras are {baseline / depth:.1%} of the scene depth apart, and no "
                       "homography explains the pair")
            elif unc > p.recon_max_uncertainty_frac * max(sizes[i]) and not _takes_over(cams.F(i, j), g,
                                                                                         max(sizes[i]), p):
                why = f"epipolar lines too uncertain ({unc:.1f} px)"
            elif not g.ok and not p.recon_rescue_planar and (g.homography_share > p.max_homography_share
                                                              or 0.0 < g.spread < p.min_spread):
                # the pair's matches lie on one plane or in one patch: they agree with the cameras' F
                # there and cannot check it elsewhere, where the two-view F was free as well (arc 0-4,
                # plaza 0-1: 0.2 px from their matches, 10-40 px off on the rest of the scene)
                where = "on one plane" if g.homography_share > p.max_homography_share else "in one patch"
                why = (f"its matches lie {where} ({g.reason}), so they cannot check the cameras' F "
                       "anywhere else")
            if why is not None:
                if g.ok:              # the pair's own two-view geometry passed its tests: it stays
                    continue
                new = dataclasses.replace(g, status=REJECTED, source="", uncertainty_px=unc, reason=why)
            else:
                # the matches that the reconstruction confirmed (track observations in both photos)
                oi = cams.obs[rows[i][np.isin(cams.obs[rows[i], 0], common)]]
                oj = cams.obs[rows[j][np.isin(cams.obs[rows[j], 0], common)]]
                oi, oj = oi[np.argsort(oi[:, 0], kind="stable")], oj[np.argsort(oj[:, 0], kind="stable")]
                _, fi = np.unique(oi[:, 0], return_index=True)
                _, fj = np.unique(oj[:, 0], return_index=True)
                idx = np.column_stack([oi[fi, 2], oj[fj, 2]]).astype(np.int32)
                new = dataclasses.replace(g, F=cams.F(i, j), status=OK, reason="", source=RECONSTRUCTION,
                                          uncertainty_px=unc, inlier_idx=idx, n_inliers=len(idx),
                                          inliers_ref=keypoints[i][idx[:, 0]].astype(np.float32),
                                          inliers_sup=keypoints[j][idx[:, 1]].astype(np.float32))
            out[(i, j)] = new
            out[(j, i)] = new.reversed()
    return out


# ----------------------------------------------------------------------------- export
def cameras_in_original_frame(cams: SetCameras, k: int, scale: float) -> dict:
    """Photo k's camera in its original-resolution pixel frame (our convention: (0, 0) is the
    centre of the top-left pixel; x = K R (X - C)), as lists for JSON."""
    from .geometry import scale_matrix
    K = np.linalg.inv(scale_matrix(scale)) @ cams.K[k]
    return {"K": K.tolist(), "R": cams.R[k].tolist(), "C": cams.C[k].tolist()}


def export_colmap_text(cams: SetCameras, photos, keypoints: list[np.ndarray], out_dir) -> None:
    """Write the registered cameras, their observations and the sparse points in COLMAP's text
    format (cameras.txt, images.txt, points3D.txt) at each photo's original resolution, so that
    COLMAP's GUI, nerfstudio or Rerun can open it. Image names are the photos' file names."""
    from pathlib import Path

    from .geometry import scale_matrix
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    reg = [k for k in range(len(photos)) if cams.registered[k]]
    keep_pts = np.isin(cams.obs[:, 1], reg)
    obs = cams.obs[keep_pts]
    lines_c = ["# Camera list with one line of data per camera:", "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]"]
    lines_i = ["# Image list with two lines of data per image:",
               "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME", "#   POINTS2D[] as (X, Y, POINT3D_ID)"]
    slot = {}                                          # (point, photo) -> index in that image's POINTS2D
    for cid, k in enumerate(reg, start=1):
        ph = photos[k]
        s = ph.scale
        K = np.linalg.inv(scale_matrix(s)) @ cams.K[k]          # original frame, our convention
        H, W = ph.orig_size
        lines_c.append(f"{cid} PINHOLE {W} {H} " + _num(K[0, 0], K[1, 1], K[0, 2] + 0.5, K[1, 2] + 0.5))
        q = _quaternion(cams.R[k])
        t = -cams.R[k] @ cams.C[k]
        lines_i.append(f"{cid} {_num(*q, *t)} {cid} {ph.name}")
        mine = obs[obs[:, 1] == k]
        pts2d = []
        for n_, (pt, _, kp) in enumerate(mine):
            x, y = (keypoints[k][kp] + 0.5) / s                   # COLMAP: (0.5, 0.5) is the first pixel's centre
            pts2d.append(f"{_num(x, y)} {int(pt) + 1}")
            slot[(int(pt), k)] = n_
        lines_i.append(" ".join(pts2d))
    lines_p = ["# 3D point list with one line of data per point:",
               "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)"]
    image_id = {k: cid for cid, k in enumerate(reg, start=1)}
    for pt in np.unique(obs[:, 0]):
        track = [(image_id[int(k)], slot[(int(pt), int(k))]) for _, k, _ in obs[obs[:, 0] == pt]]
        X, rgb = cams.points[pt], cams.point_rgb[pt]
        lines_p.append(f"{int(pt) + 1} {_num(*X)} {rgb[0]} {rgb[1]} {rgb[2]} {_num(cams.point_error[pt])} "
                       + " ".join(f"{a} {b}" for a, b in track))
    for name, lines in (("cameras.txt", lines_c), ("images.txt", lines_i), ("points3D.txt", lines_p)):
        (out / name).write_text("\n".join(lines) + "\n")


def _num(*values) -> str:
    return " ".join(repr(float(v)) for v in values)


def _quaternion(R: np.ndarray) -> np.ndarray:
    """(w, x, y, z) unit quaternion of a rotation matrix, w >= 0."""
    m = R
    tr = np.trace(m)
    if tr > 0:
        s = 2.0 * np.sqrt(tr + 1.0)
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    q = np.array(q)
    q /= np.linalg.norm(q)
    return q if q[0] >= 0 else -q


def ground_plane(cams: SetCameras, min_share: float = 0.2, max_tilt_deg: float = 30.0, seed: int = 0
                 ) -> tuple[np.ndarray, float] | None:
    """The set's ground, if its sparse points show one: (n_w unit normal pointing up, d_w) with
    n_w . X + d_w = 0 on the ground, or None.

    The dominant plane of the sparse points (RANSAC, a 1 % band of the scene's extent) is the
    ground when it holds at least `min_share` of the points, its normal is within `max_tilt_deg`
    of the cameras' mean "up" (the negated image y axis), and most cameras are above it.
    """
    X = cams.points
    reg = np.nonzero(cams.registered)[0]
    if len(X) < 30 or len(reg) < 2:
        return None
    up = -np.mean([cams.R[k][1] for k in reg], axis=0)
    up /= np.linalg.norm(up)
    band = 0.01 * float(np.median(np.linalg.norm(X - np.median(X, axis=0), axis=1)))
    rng = np.random.default_rng(seed)
    best, best_n, best_d = 0, None, None
    for _ in range(400):                      # hypotheses, each tested on all points at once
        s = X[rng.choice(len(X), 3, replace=False)]
        n = np.cross(s[1] - s[0], s[2] - s[0])
        if np.linalg.norm(n) < 1e-12:
            continue
        n /= np.linalg.norm(n)
        if n @ up < 0:
            n = -n
        if np.degrees(np.arccos(np.clip(n @ up, -1, 1))) > max_tilt_deg:
            continue
        d = -n @ s[0]
        k = int(np.sum(np.abs(X @ n + d) < band))
        if k > best:
            best, best_n, best_d = k, n, d
    if best_n is None or best < min_share * len(X):
        return None
    inl = np.abs(X @ best_n + best_d) < band                 # refit on the inliers (least squares)
    c = X[inl].mean(axis=0)
    # the thin SVD: the full one also makes the (N, N) left factor, 1.2 GB for a hundred photos' points
    n = np.linalg.svd(X[inl] - c, full_matrices=False)[2][-1]
    n = n if n @ up >= 0 else -n
    d = float(-n @ c)
    if np.mean(cams.C[reg] @ n + d > 0) < 0.5:
        return None
    return n, d
