"""Run the method on a photo set: features -> geometry -> support sets -> pairs -> aggregation.

`detect_set` is the one entry point used by the CLI, the benchmark, the Rerun logger and the
inspector. Per-pair work runs in a process pool (both cores) and is cached on disk.
"""

from __future__ import annotations

import dataclasses
import io
import json
import multiprocessing as mp
import os
import threading
import time
from collections import OrderedDict
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, ThreadPoolExecutor, as_completed, wait
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable

import numpy as np

from . import cache as cache_mod
from .aggregate import (Normaliser, combine, cumulative_dynamic, dynamic_from_log_odds, match_probability,
                        support_log_odds)
from .descriptors import image_channels_for
from .features import Features, detect
from .loading import InputError, PhotoSet
from .homography import match_pair_homography
from .jit import one_thread_per_caller
from .matching import PairResult, match_pair
from .memory import keep_freed_memory
from .params import Params
from .photometric import normalise_to_reference
from .refine import refine
from .reconstruction import SetCameras, apply_reconstruction, ground_plane, reconstruct
from .store import PairStore, light_of
from .screen import screen_pairs, shared_features
from .support import (PairGeometry, cap_supports, estimate_pair, not_compared, position_keys, support_sets,
                      triplet_check, uncertainty_gate)
from .peer import PeerPair, difference, dynamic_from_differences, plane_difference, plane_log_odds
from .homography import aligned_support, reach_distance
from .photometric import normalise_aligned
from .pencil import shared_pencil
from .sweep import (Fused, SweepPair, aligned_pair, depth_span_px, fuse, inverse_depths, on_grid, pencil_pair,
                    reference_planes, sweep_pair)

Progress = Callable[[str, int, int], None]


class Cancelled(Exception):
    """detect_set was stopped through its `cancel` event."""
MAP_FIELDS = ("hog_map", "color_map", "evidence", "plane_diff")
MAPS_VERSION = "3"      # bump when a change alters how pair results become a photo's map (its cache key)


@dataclass
class SetResult:
    """Everything computed for a set, at working resolution.

    pairs: geometry per ordered pair (i, j); supports[i]: admitted support indices of photo i;
    pair_results[(i, j)]: matching result for every admitted ordered pair;
    normaliser: set-level confidence ranges (§3.1.2); dynamic[i]: (h_i, w_i) float32 P_dynamic,
    or None when photo i has no support; keypoints[i]: (N_i, 2) float32 SIFT positions.
    """

    params: Params
    photo_set: PhotoSet
    pairs: dict[tuple[int, int], PairGeometry]
    supports: list[list[int]]
    pair_results: "Mapping[tuple[int, int], PairResult]"     # a store.PairStore (or a dict)
    normaliser: Normaliser
    dynamic: list[np.ndarray | None]
    timings: dict[str, float] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    keypoints: list[np.ndarray] = field(default_factory=list)
    cameras: SetCameras | None = None
    cache_hits: int = 0
    cache_misses: int = 0
    _fused: dict = field(default_factory=dict, repr=False, compare=False)
    _spans: dict = field(default_factory=dict, repr=False, compare=False)
    _pencil_base: dict = field(default_factory=dict, repr=False, compare=False)

    def is_swept(self, i: int, j: int) -> bool:
        """The pair has a sweep (sweep.py) for photo i's depth cue: a cost volume over the set's
        cameras' planes or over a pencil without cameras, or an aligned pair's direct comparison."""
        return self.sweep_kind(i, j) is not None

    def sweep_kind(self, i: int, j: int) -> str | None:
        """The kind of the pair's sweep (SweepPair.kind, without loading an evicted pair): "sweep"
        (the set's cameras), "aligned" (a homography pair compared directly), "two-view" (its
        reference's pencil of planes without cameras, pencil.py), or None when it has none."""
        if (i, j) not in self.pair_results or not _light(self.pair_results, (i, j)).swept:
            return None
        g = self.pairs[(i, j)]
        if _sweepable((i, j), g, self.cameras, self.params, self.photo_set.photos[i].size):
            return "sweep"
        return "aligned" if g.is_homography else "two-view"

    def kind(self, i: int, j: int) -> str:
        """"epipolar", "homography" or "peer" (without loading an evicted pair)."""
        return _light(self.pair_results, (i, j)).kind

    def fused(self, i: int, supports: list[int], params: Params | None = None) -> Fused | None:
        """The depth-consistent fusion of photo i's swept supports among `supports` (sweep.fuse),
        or None when none is swept. Cached per support set (the fusion is the costly step)."""
        sw = tuple(j for j in supports if self.is_swept(i, j))
        if not sw:
            return None
        p = params or self.params
        sp = p.sweep
        key = (i, sw, sp)        # every sweep setting (SweepParams is frozen, so hashable): none can be left out
        f = self._fused.get(key)
        if f is None:
            # the result is returned from this local: another thread (photos' maps are made in
            # threads, the inspector's tabs fuse in theirs) may clear the cache in between
            f = fuse(self.sweep_pairs(i, sw), sp, self.same_spot(i, sw, p))
            if len(self._fused) > 32:
                self._fused.clear()
            self._fused[key] = f
        return f

    def lone_pencil(self, i: int) -> int | None:
        """The support of photo i whose pair is swept over a pencil of planes made from it alone
        (pencil.py; no other support's shared tracks checked its F), or None. Decided from the
        geometry, as the run planned the pencil (run._pencil_of), not from the pairs finished so
        far: a partial result (the inspector's, while pairs arrive) counts a two-support pencil
        whole from its first pair on."""
        if i not in self._pencil_base:
            photos = self.photo_set.photos
            swept = {(i, j) for j in self.supports[i]
                     if _sweepable((i, j), self.pairs[(i, j)], self.cameras, self.params, photos[i].size)}
            ps_i = _pencil_of(i, self.supports[i], self.pairs, swept, photos, self.params)
            self._pencil_base[i] = tuple(ps_i.base) if ps_i is not None else ()
        base = self._pencil_base[i]
        return base[0] if len(base) == 1 else None

    def sweep_pairs(self, i: int, swept: list[int]) -> list[SweepPair]:
        """The SweepPairs of photo i's `swept` supports on one grid, the coarsest of theirs: a direct
        comparison made on a finer grid (`sweep.aligned_side`) keeps it only where every swept support
        is one; beside the planes' volumes it is sampled down to theirs (sweep.on_grid)."""
        pairs = [self.pair_results[(i, j)].sweep for j in swept]
        grid = min((p.cost.shape[:2] for p in pairs), key=lambda g: g[0] * g[1])
        return [on_grid(p, grid) for p in pairs]

    def same_spot(self, i: int, supports, params: Params | None = None) -> np.ndarray:
        """(S,) bool for the swept `supports` of photo i: taken from i's own spot (a direct
        comparison: an aligned pair, or cameras whose match moves less than `sweep.same_spot_frac` of
        the working side over i's depth range, sweep.depth_span_px). Such supports always count in the
        fusion."""
        p = params or self.params
        out = np.zeros(len(supports), bool)
        if not p.sweep.same_spot_frac > 0:
            return out
        limit = p.sweep.same_spot_frac * p.max_side       # a length that follows the working size
        for k, j in enumerate(supports):
            kind = self.sweep_kind(i, j)
            if kind == "aligned":
                out[k] = True
            elif kind == "sweep" and self.cameras is not None and self.cameras.registered[i] \
                    and self.cameras.registered[j]:
                out[k] = self.depth_span(i, j) < limit
        return out

    def depth_span(self, i: int, j: int) -> float:
        """sweep.depth_span_px of the pair (i, j) over i's depth range, working px (cached)."""
        if (i, j) not in self._spans:
            c = self.cameras
            self._spans[(i, j)] = depth_span_px((c.K[i], c.R[i], c.C[i]), (c.K[j], c.R[j], c.C[j]),
                                                float(c.depth_range[i][0]), self.photo_set.photos[i].size)
        return self._spans[(i, j)]

    def sweep_log_odds(self, i: int, supports: list[int], params: Params | None = None) -> np.ndarray | None:
        """The depth-consistent cue as static log-odds, (h, w) float32 (0 where no support sees
        the point), or None when no support among `supports` is swept."""
        p = params or self.params
        f = self.fused(i, supports, p)
        if f is None:
            return None
        # a point that one support alone sees has no agreement to speak of: the cue counts in full
        # from `sweep.full_support` supports on, in proportion below
        trust = np.clip((f.n_seen.astype(np.float32) - 1.0) / max(p.sweep.full_support - 1, 1), 0.0, 1.0) \
            if p.sweep.full_support > 1 else 1.0
        if [j for j in supports if self.is_swept(i, j)] == [self.lone_pencil(i)]:
            # the cue rests on one support's F, which no other support's answers to (pencil.py aligns two or
            # more on shared tracks): an F right on its matches' plane and wrong off it reads the rest as
            # motion (facade_repeat's cam00, 36 px off at the 90th percentile: static above 0.5 0.78 -> 1.61 %)
            trust = trust * p.sweep.lone_pencil_weight
        return self._upsample(i, trust * np.nan_to_num(calibrated_log_odds(f.cost, p), nan=0.0))

    def static_log_odds(self, i: int, supports: list[int], params: Params | None = None) -> np.ndarray:
        """Evidence that photo i's pixels are static, as log-odds (h, w) float32: Eq. 3's term of
        every support (per-support strips, homography pairs) plus the depth-consistent cue of the
        swept ones (sweep_log_odds, weighted by `sweep.weight`). 0 is no evidence."""
        p = params or self.params
        logit = self.strips_log_odds(i, supports, p)
        sw = self.sweep_log_odds(i, supports, p) if p.sweep.weight > 0 else None
        if sw is not None:
            logit += p.sweep.weight * sw
        return logit

    def strips_log_odds(self, i: int, supports: list[int], params: Params | None = None) -> np.ndarray:
        """The strips' part of static_log_odds, (h, w) float32: Eq. 3's term of every support
        (per-support strips, homography pairs), a swept support's weighted by
        `aggregate.swept_strips`, averaged over the supports with `aggregate.mean_terms`."""
        p = params or self.params
        logit = np.zeros(self.photo_set.photos[i].size, np.float32)
        count = np.zeros(self.photo_set.photos[i].size, np.float32)
        for j in supports:
            w = p.aggregate.swept_strips if p.sweep.weight > 0 and self.is_swept(i, j) else 1.0
            if w == 0:
                continue
            logit += w * support_log_odds(self.match_prob(i, j, p), p.aggregate)
            count += w * (self.pair_results[(i, j)].evidence > 0.05)
        if p.aggregate.mean_terms:       # per support: comparable across photos with few and many supports
            logit /= np.maximum(count, 1.0)
        return logit

    def plane_log_odds(self, i: int, supports: list[int], params: Params | None = None) -> np.ndarray | None:
        """The plane-aligned difference over `supports` as static log-odds (peer.plane_log_odds),
        (h, w) float32; None when the map does not use the cue (Params.plane_cue) or no support has
        such a difference (no homography of its matches)."""
        p = params or self.params
        if not p.plane_cue:
            return None
        diffs = self.plane_diffs(i, supports)
        return np.maximum(plane_log_odds(diffs, p.aggregate.plane_neutral), -p.aggregate.plane_dynamic_cap) \
            if diffs else None

    def plane_diffs(self, i: int, supports: list[int]) -> list[np.ndarray]:
        """The (h, w) float32 plane-aligned differences of photo i's `supports` that have one
        (PairResult.plane_diff), in their order; peer.median_difference gives their median."""
        return [d for j in supports if (d := getattr(self.pair_results[(i, j)], "plane_diff", None)) is not None]

    def with_plane_cue(self, i: int, supports: list[int], dyn: np.ndarray, params: Params | None = None) -> np.ndarray:
        """P_dynamic (h, w) float32 with the plane-aligned difference added to its log-odds,
        `aggregate.plane_weight` x plane_log_odds; dyn unchanged without the cue. Added after the
        calibration and the guided filter: the difference is sharp at a mover's outline, and the
        filter would blur it (measured: added before, every bundled set gained less, `Slide` lost)."""
        p = params or self.params
        z = self.plane_log_odds(i, supports, p)
        if z is None:
            return dyn
        d = np.clip(dyn.astype(np.float64), 1e-6, 1 - 1e-6)
        return dynamic_from_log_odds(np.log((1 - d) / d) + p.aggregate.plane_weight * z)

    def dynamic_prob(self, i: int, supports: list[int], params: Params | None = None) -> np.ndarray:
        """P_dynamic of photo i from the given supports: Eq. 3 (and, with the sweep, the
        depth-consistent cue and the calibration); then the optional refinement."""
        p = params or self.params
        if p.geometry.peer_homography:
            return self.refine_dynamic(i, dynamic_from_differences([self.pair_results[(i, j)].diff for j in supports]), p)
        if not p.sweep.enabled:
            return self.refine_dynamic(i, combine([self.match_prob(i, j, p) for j in supports], p.aggregate), p)
        return self.dynamic_from_static(i, supports, self.static_log_odds(i, supports, p), p)

    def dynamic_from_static(self, i: int, supports: list[int], z: np.ndarray, params: Params | None = None
                            ) -> np.ndarray:
        """P_dynamic (h, w) float32 of photo i from its static log-odds z (static_log_odds): the
        calibration, the refinement and the plane-aligned difference (`crowdcam calibrate` asks for
        the final map at several offsets without making z again)."""
        p = params or self.params
        a = p.aggregate
        dyn = dynamic_from_log_odds(a.calib_scale * (z - a.calib_offset * self.sweep_seen(i, supports, p)))
        # a point no support speaks about is no evidence, never motion (EVIDENCE_NOTES point 7)
        dyn = self.refine_dynamic(i, np.where(self.has_evidence(i, supports, p), dyn, 0.5).astype(np.float32), p)
        return self.with_plane_cue(i, supports, dyn, p)

    def sweep_seen(self, i: int, supports: list[int], params: Params | None = None) -> np.ndarray:
        """(h, w) float32 where the calibration's offset applies: 1 over the whole photo when some
        support among `supports` is swept, else 0. `crowdcam calibrate` fits it over every pixel of
        such photos, the depth cue's and the strips' alike (applied only where a swept support sees
        the point, the strips' pixels beside them read more dynamic than the fit meant: `Slide`
        0.30 against 0.32); a photo without the depth cue keeps Eq. 3's decision at 0.5."""
        p = params or self.params
        swept = p.sweep.weight > 0 and any(self.is_swept(i, j) for j in supports)
        return np.full(self.photo_set.photos[i].size, 1.0 if swept else 0.0, np.float32)

    def has_evidence(self, i: int, supports: list[int], params: Params | None = None) -> np.ndarray:
        """(h, w) bool: some support had a candidate for the pixel (Eq. 2 evidence) or saw it at
        the shared depth."""
        p = params or self.params
        seen = np.zeros(self.photo_set.photos[i].size, bool)
        for j in supports:
            r = self.pair_results[(i, j)]
            if hasattr(r, "evidence"):
                seen |= r.evidence > 0.05
        f = self.fused(i, supports, p) if p.sweep.weight > 0 else None
        if f is not None:
            seen |= self._upsample(i, (f.n_seen > 0).astype(np.float32)) > 0.5
        return seen

    def sweep(self, i: int, params: Params | None = None) -> list[np.ndarray]:
        """P_dynamic of photo i after its first 1, 2, ... k supports (the paper's Fig. 5); the last
        equals dynamic_prob(i, supports[i])."""
        p = params or self.params
        if p.geometry.peer_homography or p.sweep.enabled:
            return [self.dynamic_prob(i, self.supports[i][:k], p) for k in range(1, len(self.supports[i]) + 1)]
        probs = [self.match_prob(i, j, p) for j in self.supports[i]]
        return [self.refine_dynamic(i, d, p) for d in cumulative_dynamic(probs, p.aggregate)]

    def _upsample(self, i: int, grid_map: np.ndarray) -> np.ndarray:
        """(gh, gw) sweep-grid map -> (h, w) float32 at working resolution."""
        import cv2
        h, w = self.photo_set.photos[i].size
        return cv2.resize(grid_map.astype(np.float32), (w, h), interpolation=cv2.INTER_LINEAR)

    def refine_dynamic(self, i: int, dyn: np.ndarray, params: Params | None = None) -> np.ndarray:
        """The optional final refinement of photo i's P_dynamic (refine.py); identity when off."""
        p = params or self.params
        r = int(round(p.aggregate.refine_radius_frac * p.max_side))
        return refine(dyn, self.photo_set.photos[i].rgb, r, p.aggregate.refine_eps) if r > 0 else dyn

    def explain(self, i: int, j: int, patch_ids: np.ndarray | None = None, pixels: np.ndarray | None = None):
        """Candidate evidence (explain.PatchEvidence) for patches of epipolar pair (i, j), given
        by patch id or as the patches covering (N, 2) reference pixels."""
        from .explain import explain_patches, patches_at
        r, g = self.pair_results[(i, j)], self.pairs[(i, j)]
        if patch_ids is None:
            patch_ids = np.unique(np.concatenate(patches_at(r, pixels)))
        rgbs = [p.rgb for p in self.photo_set.photos]
        ch_ref = image_channels_for(rgbs[i], self.params.descriptors)
        return explain_patches(r, ch_ref, support_channels(rgbs[i], rgbs[j], g, self.params), g.F, g.scale,
                               self.params, patch_ids)

    def match_prob(self, i: int, j: int, params: Params | None = None) -> np.ndarray:
        """P(x|I_j) for reference i, (h, w) float32 (Eq. 2; for the peer baseline, how well the
        aligned colours agree)."""
        p = params or self.params
        r = self.pair_results[(i, j)]
        if r.kind == "peer":                      # how well the aligned support matches: 1 = same colour
            return np.where(np.isnan(r.diff), 0.5, np.exp(-np.nan_to_num(r.diff) / 15.0)).astype(np.float32)
        return match_probability(r.hog_map, r.color_map, r.evidence, self.normaliser, p.descriptors, p.aggregate)

    def depth_match_prob(self, i: int, j: int, supports: list[int], params: Params | None = None
                         ) -> np.ndarray | None:
        """What swept support j said at the depth all swept `supports` agreed on: its cost there,
        calibrated like the fused cost, as a match probability (h, w) float32 (0.5 where it does
        not see the point); None when the pair is not swept."""
        p = params or self.params
        if not self.is_swept(i, j):
            return None
        sw = [k for k in supports if self.is_swept(i, k)]
        f = self.fused(i, sw, p)
        c = f.per_support[sw.index(j)]
        q = 1.0 / (1.0 + np.exp(-np.nan_to_num(calibrated_log_odds(c, p), nan=0.0)))
        return np.clip(self._upsample(i, q), 0.0, 1.0)


def calibrated_log_odds(cost: np.ndarray, params: Params) -> np.ndarray:
    """Static log-odds of a fused (or per-support) sweep cost, (h, w) float32; NaN stays NaN
    (callers treat it as 0, no evidence). Monotone: a lower cost is more static."""
    sp = params.sweep
    return (sp.calib_slope * (sp.calib_centre - np.asarray(cost, np.float32))).astype(np.float32)


def support_channels(rgb_ref: np.ndarray, rgb_sup: np.ndarray, g: PairGeometry, params: Params):
    """Descriptor inputs of the support for this pair: its colours mapped to the reference's when
    the preset normalises colour (photometric.py), else the support as it is."""
    rgb = rgb_sup
    if params.descriptors.color_normalise:
        rgb = normalise_to_reference(rgb_ref, rgb_sup, g.inliers_ref, g.inliers_sup)
    return image_channels_for(rgb, params.descriptors)


# ----------------------------------------------------------------------------- workers
_W: dict = {}
_INLINE = threading.Lock()      # inline runs (one worker) take turns with the per-process state _W


def _init_worker(rgbs: list[np.ndarray], params: Params) -> None:
    import signal

    import cv2
    cv2.setNumThreads(1)
    if mp.parent_process() is not None:        # a pool worker: Ctrl-C is the main process's to handle
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        keep_freed_memory()                    # its large arrays reused pair after pair (pipeline/memory.py)
        threading.Thread(target=_exit_with_parent, args=(os.getppid(),), daemon=True).start()
        if "NUMBA_NUM_THREADS" not in os.environ:    # the workers fill the cores: one thread each
            import numba
            numba.set_num_threads(1)
    _W["rgbs"], _W["params"], _W["channels"] = rgbs, params, {}


def _exit_with_parent(parent: int) -> None:
    """A worker whose main process is gone (killed: SIGKILL, the out-of-memory killer) leaves too.
    It waited on its task queue for ever otherwise, holding its memory; its parent then changes."""
    while os.getppid() == parent:
        time.sleep(1.0)
    os._exit(1)


def _init_worker_from_files(folder: str, n: int, params: Params) -> None:
    """_init_worker with the photos read from `folder` (_Runner writes them there, one .npy each)."""
    _init_worker([np.load(os.path.join(folder, f"{k}.npy")) for k in range(n)], params)
    _W["folder"] = folder


_FEATURE_FIELDS = ("xy", "size", "desc", "response")


def _worker_features(k: int) -> Features:
    """Photo k's features in a pool worker, from the files _Runner.share_features wrote; the
    last 32 read are kept (a photo's geometry tasks come together: (i, j) for j after i)."""
    kept = _W.setdefault("features", OrderedDict())
    if k not in kept:
        path = lambda f: os.path.join(_W["folder"], f"features-{k}-{f}.npy")
        arrays = {f: np.load(path(f)) if os.path.exists(path(f)) else None for f in _FEATURE_FIELDS}
        kept[k] = Features(**arrays)            # (responses unknown: no file, None)
        while len(kept) > 32:
            kept.popitem(last=False)
    kept.move_to_end(k)
    return kept[k]


def _channels(i: int):
    ch = _W["channels"]
    if i not in ch:
        ch[i] = image_channels_for(_W["rgbs"][i], _W["params"].descriptors)
    return ch[i]


def _task_features(i: int) -> tuple[int, Features]:
    gp = _W["params"].geometry
    return i, detect(_W["rgbs"][i], gp.sift_features, gp.sift_contrast, gp.affine_tilts)


def _task_geometry(i: int, j: int, fi: Features | None = None, fj: Features | None = None
                   ) -> tuple[tuple[int, int], bytes]:
    """The geometry of photos i and j; their features given, or (None) read from the files that
    _Runner.share_features wrote for the pool."""
    rgbs, p = _W["rgbs"], _W["params"]
    fi = fi if fi is not None else _worker_features(i)
    fj = fj if fj is not None else _worker_features(j)
    g = estimate_pair(i, j, fi, fj, rgbs[i].shape[:2], rgbs[j].shape[:2], p.geometry)
    return (i, j), cache_mod.to_bytes(g)


def _fault_injection(i: int, j: int) -> None:
    """Deterministic faults for the tests (tests/test_faults.py), off unless CROWDCAM_FAULT is set:
    "kill:I,J" kills the worker on pair (I, J) (once, if CROWDCAM_FAULT_ONCE names a marker file
    that does not exist yet), "hang:I,J" makes it wait forever after touching CROWDCAM_FAULT_ONCE."""
    spec = os.environ.get("CROWDCAM_FAULT")
    if not spec:
        return
    what, _, ij = spec.partition(":")
    if ij != f"{i},{j}":
        return
    marker = os.environ.get("CROWDCAM_FAULT_ONCE")
    if what == "kill":
        if marker:
            if os.path.exists(marker):
                return
            open(marker, "w").close()
        os.kill(os.getpid(), 9)
    if what == "hang":
        if marker:
            open(marker, "w").close()
        while True:
            time.sleep(1)


def _task_pair(i: int, j: int, g: PairGeometry, sweep_args: tuple | None = None,
               store_in: tuple[str, str] | None = None) -> tuple[tuple[int, int], bytes | None, bytes, int]:
    """One ordered pair: strips (epipolar pair) or aligned patches (homography pair), and with
    sweep_args = (cam_i, cam_j, inverse depths) also its cost volume over the depth planes.
    Returns (i, j), the result's bytes, its summary's (store.light_of: what the main process keeps
    of every pair, so that it need not decode the result to make it; the summary's fields are stored
    exactly, so it equals the decoded result's) and 0; or, with store_in = (cache folder, key), the
    result written there as the pair's entry (PairCache.write), None in its place and the bytes
    written (the result's bytes after all if it could not be written)."""
    (i, j), data, light = _pair_result(i, j, g, sweep_args)
    if store_in is not None:
        stored = cache_mod.PairCache(Path(store_in[0]), max_bytes=None).write("pair", store_in[1], data)
        if stored:
            return (i, j), None, light, stored
    return (i, j), data, light, 0


def _pair_result(i: int, j: int, g: PairGeometry, sweep_args: tuple | None) -> tuple[tuple[int, int], bytes, bytes]:
    _fault_injection(i, j)
    p = _W["params"]
    rgb_i, rgb_j = _W["rgbs"][i], _W["rgbs"][j]
    if p.geometry.peer_homography:
        r = difference(i, j, rgb_i, rgb_j, g.H)
        return (i, j), cache_mod.to_bytes(r, float16=("diff",)), cache_mod.to_bytes(light_of(r))
    normalised = normalise_to_reference(rgb_i, rgb_j, g.inliers_ref, g.inliers_sup) \
        if p.descriptors.color_normalise else rgb_j
    if g.is_homography:
        r = match_pair_homography(i, j, rgb_i, rgb_j, g.H, p, g.inliers_ref)
    else:
        ch_sup = image_channels_for(normalised, p.descriptors) if p.descriptors.color_normalise else _channels(j)
        pm = p
        if sweep_args is not None and p.patches.swept_fans > 0:     # fewer fans where the depth cue speaks too
            pm = p.replace(patches=dataclasses.replace(p.patches, n_fans=p.patches.swept_fans))
        r = match_pair(i, j, _channels(i), ch_sup, g.F, g.scale, pm)
    if sweep_args is not None and sweep_args[0] == "pencil":
        r = dataclasses.replace(r, sweep=pencil_pair(i, j, rgb_i, normalised, sweep_args[1], p.sweep))
    elif sweep_args is not None:
        r = dataclasses.replace(r, sweep=sweep_pair(i, j, rgb_i, normalised, *sweep_args, p.sweep))
    elif g.is_homography and p.sweep.enabled and p.sweep.direct_homography \
            and g.uncertainty_px <= p.sweep.direct_max_parallax_frac * max(rgb_i.shape[:2]):
        # shots from one spot without cameras: compare the aligned pixels directly, where H is trusted
        h, w = rgb_i.shape[:2]
        warped, inside = aligned_support(rgb_j, g.H, (h, w))
        if p.descriptors.color_normalise:
            warped = normalise_aligned(rgb_i, warped, inside > 0)
        # pixels compared directly must lie where H is confirmed: inside the hull of its inliers (and
        # `direct_reach_frac` beyond); parallax past it reads as change at once, unlike the patch search
        inside = inside * (reach_distance(g.inliers_ref, (h, w)) <= p.sweep.direct_reach_frac * max(h, w))
        r = dataclasses.replace(r, sweep=aligned_pair(i, j, rgb_i, warped, inside.astype(np.float32), p.sweep))
    if p.plane_cue:
        # the plane-aligned difference (peer.py's cue, one term of our fusion): every match of the pair
        diff, _ = plane_difference(i, j, rgb_i, rgb_j, np.concatenate([g.inliers_ref, g.outliers_ref]),
                                   np.concatenate([g.inliers_sup, g.outliers_sup]), p.geometry.ransac_px * 2.0,
                                   p.geometry.min_inliers)
        r = dataclasses.replace(r, plane_diff=diff)
    return (i, j), cache_mod.to_bytes(r, float16=MAP_FIELDS, delta=("sweep.cost",)), cache_mod.to_bytes(light_of(r))


class WorkerDied(RuntimeError):
    """A worker process died twice (out-of-memory killer, a kill) while computing the named task."""


class _Runner:
    """Runs tasks in a spawn-based process pool, or inline for one worker.

    A worker that dies (BrokenProcessPool) takes the pool with it: the pool is rebuilt and the
    unfinished tasks are retried once; a task unfinished at a second death raises WorkerDied.
    Results delivered before (and cached by on_done) are kept. On any other exception, Ctrl-C
    included, the workers are terminated at once (they ignore SIGINT themselves), so a stop takes
    no longer than the process exits.

    urgent (optional): a test of a task's arguments, asked each time a task is handed to a worker;
    the first waiting task that passes goes next, else the first in order. With it, at most
    workers + 2 tasks are in the pool at a time, so that a change of mind (a viewer's reference)
    waits for those alone; without it, every task is queued at once."""

    on_this_machine = True        # its workers share this machine's files (share_features, the cache)

    def __init__(self, rgbs: list[np.ndarray], params: Params, workers: int):
        self.workers = workers
        self.pool = None
        self.args = (rgbs, params)
        self._folder: str | None = None

    def _ensure_pool(self) -> None:
        if self.pool is None:
            # one BLAS thread per worker (read when a worker loads numpy, so it goes in the environment
            # they inherit); numba's threads are set in the worker itself (_init_worker): numba reads
            # NUMBA_NUM_THREADS again at every compile, and in this process, once its threads had
            # started, a kernel compiled later raised "Cannot set NUMBA_NUM_THREADS to a different value"
            for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
                os.environ.setdefault(var, "1")
            self.pool = ProcessPoolExecutor(self.workers, mp_context=mp.get_context("spawn"),
                                            initializer=_init_worker_from_files, initargs=self._photo_files())

    def _photo_files(self) -> tuple:
        """The initializer's arguments with the photos in files (written once per runner, removed
        with it), not in the arguments themselves: those are written into each new worker's pipe
        before it starts, and a worker that dies before reading them all (a user's script that
        calls detect_set unguarded by `if __name__ == "__main__":` dies so, re-run by the spawned
        worker) left the main process blocked on that write for ever; a few hundred bytes fit the
        pipe, the pool then sees the worker die and the run ends with an error."""
        if self._folder is None:
            import shutil
            import tempfile
            import weakref
            rgbs, _ = self.args
            self._folder = tempfile.mkdtemp(prefix="crowdcam-photos-")
            weakref.finalize(self, shutil.rmtree, self._folder, True)
            for k, rgb in enumerate(rgbs):
                np.save(os.path.join(self._folder, f"{k}.npy"), rgb)
        return self._folder, len(self.args[0]), self.args[1]

    def share_features(self, feats: dict[int, Features]) -> bool:
        """Photos' features written once into the pool's folder, for geometry tasks that then carry
        only their two indices (_worker_features). Each task carried both photos' descriptors before:
        about 4 MB pickled, piped and unpickled per pair, 775 times on a hundred photos. False (pass
        them in the tasks) when the tasks run here."""
        if self.workers <= 1:
            return False
        folder = self._photo_files()[0]
        for k, f in feats.items():
            for name in _FEATURE_FIELDS:
                if getattr(f, name) is not None:
                    np.save(os.path.join(folder, f"features-{k}-{name}.npy"), getattr(f, name))
        return True

    def map(self, fn, arg_list: list[tuple], on_done: Callable[[object], None],
            label: Callable[[tuple], str] = lambda a: str(a[:2]),
            urgent: Callable[[tuple], bool] | None = None) -> None:
        if not arg_list:
            return
        if self.workers <= 1:
            waiting = list(arg_list)
            while waiting:
                a = waiting.pop(_next_task(waiting, urgent))
                with _INLINE:            # another inline run (a viewer's second preset) shares this process
                    if _W.get("owner") is not self:
                        _init_worker(*self.args)
                        _W["owner"] = self
                    result = fn(*a)
                on_done(result)
            return
        from concurrent.futures.process import BrokenProcessPool
        pending = dict(enumerate(arg_list))
        deaths: dict[int, int] = {}
        limit = len(arg_list) if urgent is None else self.workers + 2
        while pending:
            self._ensure_pool()
            futures: dict = {}
            waiting = list(pending)          # not handed to the pool yet
            try:
                def feed():
                    while waiting and len(futures) < limit:
                        k = waiting.pop(_next_task([pending[k] for k in waiting], urgent) if urgent else 0)
                        futures[self.pool.submit(fn, *pending[k])] = k
                feed()
                while futures:
                    # Wake up twice a second even when nothing finishes: Ctrl-C's signal may reach
                    # another thread of this process, and Python raises KeyboardInterrupt only when
                    # the main thread runs (an endless wait on a hung pair never stopped, under load).
                    done, _ = wait(list(futures), timeout=0.5, return_when=FIRST_COMPLETED)
                    for fut in done:
                        result = fut.result()
                        # let go of the finished future at once: it holds its result (a pair's
                        # bytes, ~8 MB), and a 100-photo set has 800 of them (the main process grew
                        # past 3 GB)
                        del pending[futures.pop(fut)]
                        on_done(result)
                        del result
                    feed()
            except BrokenProcessPool:
                self.close(kill=True)
                for k in futures.values():       # the tasks in the pool when it broke
                    deaths[k] = deaths.get(k, 0) + 1
                twice = [k for k in futures.values() if deaths[k] > 1]
                if twice:
                    why = "out of memory?" if len(pending) < len(arg_list) else \
                        ("out of memory? or, from a script, a call outside `if __name__ == \"__main__\":`, "
                         "which every worker runs again as it starts")
                    raise WorkerDied(f"a worker process died twice while computing {label(pending[twice[0]])} "
                                     f"({why}); the finished pairs are cached, a re-run resumes") from None
            except BaseException:
                for fut in futures:
                    fut.cancel()
                self.close(kill=True)
                raise

    def close(self, kill: bool = False) -> None:
        if self.pool is None:
            return
        if not kill:
            self.pool.shutdown(wait=True, cancel_futures=True)
            self.pool = None
            return
        procs = list((getattr(self.pool, "_processes", None) or {}).values())
        # The pool's feeder thread may be blocked writing a task into the pipe of a worker that is
        # about to die; joining it (the pool's manager does, and so does the interpreter's exit)
        # would then wait forever (a stop that never came, seen under load). Let it go unjoined.
        call_queue = getattr(self.pool, "_call_queue", None)
        if call_queue is not None:
            call_queue.cancel_join_thread()
        for proc in procs:
            try:
                proc.terminate()
            except Exception:
                pass
        # Do not wait on the pool's own shutdown handshake after killing its workers (its
        # management thread may wait on a result that never comes); wait on the processes, and
        # kill what a SIGTERM did not stop: no orphan outlives the run. Then the management thread,
        # taken before shutdown() drops the pool's reference to it: it closes its wake-up pipe as it
        # ends, and the interpreter's exit writes to that pipe, so an exit racing its end printed
        # "OSError: [Errno 9] Bad file descriptor" after a Ctrl-C (seen under load).
        manager = getattr(self.pool, "_executor_manager_thread", None)
        self.pool.shutdown(wait=False, cancel_futures=True)
        for proc in procs:
            proc.join(timeout=5)
            if proc.is_alive():
                proc.kill()
                proc.join(timeout=5)
        if manager is not None:
            manager.join(timeout=5)
        self.pool = None


def _next_task(waiting: list[tuple], urgent: Callable[[tuple], bool] | None) -> int:
    """The index in `waiting` of the task to hand out next: the first that `urgent` passes, else 0."""
    if urgent is not None:
        for k, a in enumerate(waiting):
            if urgent(a):
                return k
    return 0


class SchedulerError(RuntimeError):
    """The Dask scheduler given by the user cannot be reached."""


class _DaskRunner:
    """Runs the same tasks on a Dask distributed cluster (`--scheduler tcp://HOST:PORT`).

    The photos and parameters travel to every worker once, in a worker plugin that sets up the
    same per-process state as the local pool (_init_worker); tasks then carry only indices and
    pair geometry, and their results (serialised bytes) come back to be cached where the client
    runs. Dask reschedules the tasks of a worker that dies; a task that kills workers repeatedly
    ends the run with WorkerDied, like the local pool."""

    on_this_machine = False       # a worker may be elsewhere: tasks and results carry their bytes

    def __init__(self, rgbs: list[np.ndarray], params: Params, scheduler: str, timeout: float = 10.0):
        try:
            from distributed import Client
        except ImportError:                       # pragma: no cover - a dependency of the project
            raise SchedulerError("--scheduler needs the packages dask and distributed") from None
        try:
            self.client = Client(scheduler, timeout=timeout)
        except Exception as e:
            raise SchedulerError(f"{scheduler}: no Dask scheduler answered within {timeout:g} s "
                                 f"({type(e).__name__})") from None
        self.client.register_plugin(_photos_plugin(rgbs, params), name="crowdcam-photos")
        self.workers = len(self.client.scheduler_info().get("workers", {}))

    def map(self, fn, arg_list: list[tuple], on_done: Callable[[object], None],
            label: Callable[[tuple], str] = lambda a: str(a[:2]),
            urgent: Callable[[tuple], bool] | None = None) -> None:
        # urgent is not used: every task is submitted at once, and Dask fixes a task's priority then
        if not arg_list:
            return
        from distributed import as_completed as dask_completed
        from distributed.scheduler import KilledWorker
        futures = {self.client.submit(fn, *a, pure=False): a for a in arg_list}
        try:
            for fut in dask_completed(futures):
                try:
                    result = fut.result()
                except KilledWorker:
                    raise WorkerDied(f"Dask workers died repeatedly while computing {label(futures[fut])}; "
                                     "the finished pairs are cached, a re-run resumes") from None
                del futures[fut]          # the cluster forgets the result once the client lets go of it
                on_done(result)
                del result
        except BaseException:
            for fut in futures:
                fut.cancel()
            raise

    def close(self, kill: bool = False) -> None:
        self.client.close()


def _photos_plugin(rgbs, params):
    """A Dask worker plugin: the run's photos and parameters, set up once per worker process."""
    from distributed import WorkerPlugin

    class PhotosPlugin(WorkerPlugin):
        def __init__(self, rgbs, params):
            self.rgbs, self.params = rgbs, params

        def setup(self, worker=None):
            _init_worker(self.rgbs, self.params)

        def teardown(self, worker=None):
            _W.clear()
    return PhotosPlugin(rgbs, params)


def _decode_light(data: bytes):
    from .store import Light
    return cache_mod.from_bytes(Light, data)


def _check(cancel: threading.Event | None) -> None:
    if cancel is not None and cancel.is_set():
        raise Cancelled()


def _light(results, ij):
    """The in-memory summary of a pair (store.Light), from a PairStore (no loading) or a dict."""
    return results.light(ij) if hasattr(results, "light") else light_of(results[ij])


def assemble(photo_set: PhotoSet, params: Params, pairs: dict, supports: list[list[int]],
             results: dict[tuple[int, int], PairResult], keypoints: list | None = None,
             timings: dict | None = None, warnings: list | None = None, cameras: SetCameras | None = None
             ) -> SetResult:
    """A SetResult from pair results (all of them, or those finished so far), with the set-level
    normaliser of §3.1.2 over exactly these pairs; no P_dynamic computed yet."""
    n = len(photo_set.photos)
    strips = [_light(results, ij) for ij in results]
    strips = [r for r in strips if r.kind in ("epipolar", "homography")]     # not the peer's
    norm = Normaliser.from_confidences([r.conf_hog for r in strips], [r.conf_color for r in strips],
                                       params.descriptors.norm_percentile)
    kps = [k if k is not None else np.zeros((0, 2), np.float32) for k in (keypoints or [None] * n)]
    return SetResult(params, photo_set, pairs, supports, results, norm, [None] * n, timings or {},
                     warnings or [], keypoints=kps, cameras=cameras)


def _sweepable(ij: tuple[int, int], g: PairGeometry, cameras: SetCameras | None, params: Params,
               size: tuple[int, int]) -> bool:
    """The preset sweeps depths and the pair's geometry comes from the set's cameras with certain
    lines (a reconstruction pair within the uncertainty limit or not estimated, or a homography
    pair of two registered photos within it)."""
    i, j = ij
    if not (params.sweep.enabled and cameras is not None and cameras.registered[i] and cameras.registered[j]
            and np.all(np.isfinite(cameras.depth_range[i]))):
        return False
    unc = cameras.pair_unc[i, j]
    certain = bool(np.isfinite(unc)) and unc <= params.geometry.recon_max_uncertainty_frac * max(size)
    if g.source == "reconstruction":       # uncertain only where it took over a two-view F (recon_over_two_view)
        return certain or not np.isfinite(unc)
    return g.source == "homography" and certain


def _pencils(refs: list[int], supports: list[list[int]], pairs: dict, swept: set, photos, params: Params
             ) -> dict[tuple[int, int], np.ndarray]:
    """Photos without cameras: their epipolar supports swept over one pencil of planes (pencil.py).
    Returns (i, j) -> (D, 3, 3) homographies, reference -> support working px, for the pairs swept so:
    those of the photos in `refs` none of whose supports the set's cameras sweep (`swept`)."""
    out = {}
    for i in refs:
        ps_i = _pencil_of(i, supports[i], pairs, swept, photos, params)
        if ps_i is not None:
            out.update({(i, j): ps_i.homographies(j) for j in ps_i.base})
    return out


def _pencil_of(i: int, supports_i: list[int], pairs: dict, swept: set, photos, params: Params):
    """Photo i's pencil of planes (pencil.PencilSweep, its supports in .base), or None when the
    preset has none, the set's cameras sweep one of its supports (`swept`: camera-swept pairs), or
    its supports make none."""
    if not (params.sweep.enabled and params.sweep.two_view):
        return None
    cand = [j for j in supports_i if not pairs[(i, j)].is_homography and pairs[(i, j)].F is not None]
    if not cand or any((i, j) in swept for j in supports_i):
        return None
    ps_i = shared_pencil({j: (pairs[(i, j)].F, pairs[(i, j)].inliers_ref, pairs[(i, j)].inliers_sup,
                              position_keys(pairs[(i, j)].inliers_ref)) for j in cand},
                         photos[i].size, params.sweep.n_planes + params.sweep.ground_planes,
                         grid_scale=params.sweep.scale, min_supports=1, working_side=params.max_side)
    if ps_i is None:
        return None
    # one support alone has no other to check its F against (the shared tracks do that): it
    # needs lines as certain as the cameras' sweep asks (recon_max_uncertainty_frac)
    if len(ps_i.base) == 1 and not (pairs[(i, ps_i.anchor)].uncertainty_px
                                    <= params.geometry.recon_max_uncertainty_frac * max(photos[i].size)):
        return None
    return ps_i


def _digest_arrays(*arrays) -> str:
    import hashlib
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a, np.float64)
        h.update(str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()[:24]


def _task_numbered(k: int, fn: Callable, *task) -> tuple[int, object]:
    return k, fn(*task)


def set_cameras(photo_set: PhotoSet, params: Params, pairs: dict, keypoints: list[np.ndarray],
                cache: cache_mod.PairCache, runner=None,
                progress: Callable[[str, int, int], None] = lambda *a: None) -> SetCameras:
    """The checked reconstruction of the set (reconstruction.py), cached: it depends on every
    photo and on the geometry parameters. pairs: PairGeometry per unordered pair (i < j).
    runner (_Runner or _DaskRunner): where the mapping runs go, side by side (default: here)."""
    photos = photo_set.photos
    k = cache_mod.key("cameras", *[p.key for p in photos], params.geometry_key_material())
    cams = cache.load("cameras", k, lambda d: cache_mod.from_bytes(SetCameras, d))
    if cams is not None:
        return cams
    prior = np.array([p.focal_prior_px if p.focal_prior_px else np.nan for p in photos], float)

    steps = [0]              # the two-view halves, then the mapping runs

    def run_tasks(fn: Callable, tasks: list[tuple], arrived: Callable[[int, object], None]) -> None:
        total = 2 * len(params.geometry.recon_focal_guesses)
        progress("cameras", steps[0], total)

        def got(res):           # here, in the main process, while the other task goes on
            arrived(*res)
            steps[0] += 1
            progress("cameras", steps[0], total)
        runner.map(_task_numbered, [(n, fn, *t) for n, t in enumerate(tasks)], got,
                   label=lambda a: f"the reconstruction of {photo_set.root}")
    cams = reconstruct(keypoints, [p.size for p in photos], pairs, [p.rgb for p in photos], params.geometry, prior,
                       run_tasks=run_tasks if runner is not None else None)
    cache.put("cameras", k, cache_mod.to_bytes(cams))
    return cams


def default_workers() -> int:
    return max(1, min(os.cpu_count() or 1, 8))


# ----------------------------------------------------------------------------- entry point
def detect_set(photo_set: PhotoSet, params: Params, cache: cache_mod.PairCache | None = None,
               workers: int | None = None, progress: Progress | None = None,
               warn: Callable[[str], None] | None = None, only_refs: Iterable[int] | None = None,
               on_geometry: Callable[[dict, list[list[int]], SetCameras | None], int | None] | None = None,
               on_pair: Callable[[tuple[int, int]], None] | None = None,
               cancel: threading.Event | None = None, max_supports: int | None = None,
               scheduler: str | None = None, store: PairStore | None = None,
               prefer: Callable[[], int | None] | None = None) -> SetResult:
    """Compute P_dynamic for every photo of the set (or only for `only_refs`).

    For viewers that show results as they arrive: `on_geometry(pairs, supports, cameras)` is called once
    the support sets and the cameras are known (it may return a reference whose pairs are then computed first),
    `on_pair((i, j))` for every pair result put in the store (cached ones first; those are read from the
    cache when first needed). Setting `cancel` stops the run soon after (raises Cancelled).
    max_supports: at most this many supports per reference (support.cap_supports); None: 8 for sets
    of more than 9 photos, no cap below; 0: no cap. scheduler: a Dask scheduler address
    (tcp://HOST:PORT) to run the per-pair work on instead of the local process pool. store: where
    pair results go (a viewer passes its own to read them while the run goes on); only the most
    recently used stay in memory, the others reload from the cache (store.PairStore).
    prefer: asked each time a pair is handed to a worker (local pool or inline, not Dask): a reference
    whose pairs go next (a viewer's shown reference, which may change while the run goes on), or
    None for the run's own order.
    """
    cache = cache or cache_mod.PairCache(None)
    workers = default_workers() if workers is None else workers
    progress = progress or (lambda *_: None)
    params = params.for_working_side(photo_set.working_side)   # the photos' size, not the limit they met
    warnings: list[str] = []

    def _warn(msg: str) -> None:
        warnings.append(msg)
        if warn:
            warn(msg)

    photos = photo_set.photos
    n = len(photos)
    rgbs = [p.rgb for p in photos]
    timings: dict[str, float] = {}
    hits0, miss0 = cache.hits, cache.misses
    runner = _DaskRunner(rgbs, params, scheduler) if scheduler else _Runner(rgbs, params, workers)
    try:
        # 1-2. Geometry per unordered pair, cached; features only when some pair needs them.
        t0 = time.perf_counter()
        gp = params.geometry
        kkey = [cache_mod.key("keypoints", p.key, params.geometry_key_material()) for p in photos]
        keypoints: list[np.ndarray | None] = [None] * n
        for i in range(n):
            keypoints[i] = cache.load("keypoints", kkey[i], lambda d: np.load(io.BytesIO(d)))
        feats: dict[int, Features] = {}

        def ensure_features(idx) -> None:
            need = sorted(set(idx) - set(feats))
            if not need:
                return
            done = [0]

            def got_features(res):
                _check(cancel)
                feats[res[0]] = res[1]
                keypoints[res[0]] = res[1].xy
                buf = io.BytesIO()
                np.save(buf, res[1].xy)
                cache.put("keypoints", kkey[res[0]], buf.getvalue())
                done[0] += 1
                progress("features", done[0], len(need))
            runner.map(_task_features, [(i,) for i in need], got_features,
                       label=lambda a: f"the features of {photos[a[0]].path}")

        all_pairs = [(i, j) for i in range(n) for j in range(i + 1, n)]
        compared = all_pairs
        pairs: dict[tuple[int, int], PairGeometry] = {}
        if n > gp.screen_above:          # a large set: geometry only for the pairs the screen picks
            skey = cache_mod.key("screen", *(p.key for p in photos), params.geometry_key_material())
            shared = cache.load("screen", skey, lambda d: np.load(io.BytesIO(d)))
            if shared is None or shared.shape != (n, n):
                ensure_features(range(n))
                progress("screen", 0, 1)
                shared = shared_features([feats[i] for i in range(n)], gp.screen_features, gp.ratio, workers)
                buf = io.BytesIO()
                np.save(buf, shared)
                cache.put("screen", skey, buf.getvalue())
                progress("screen", 1, 1)
            screen = screen_pairs(shared, gp.screen_keep)
            compared = list(screen.pairs)
            kept = set(compared)
            for i, j in all_pairs:
                if (i, j) not in kept:
                    pairs[(i, j)] = not_compared(i, j, screen.reason(i, j, gp.screen_features))
            timings["screen_pairs"] = len(compared)
        material = params.geometry_key_material()
        gkey = {(i, j): cache_mod.key("geometry", photos[i].key, photos[j].key, material) for i, j in compared}
        todo = []
        for ij, k in gkey.items():
            g = cache.load("geometry", k, lambda d: cache_mod.from_bytes(PairGeometry, d))
            if g is not None:
                pairs[ij] = g
            else:
                todo.append(ij)
        if todo or any(k is None for k in keypoints):
            ensure_features({i for ij in todo for i in ij} | {i for i in range(n) if keypoints[i] is None})
            gdone = [0]

            def got_geometry(res):
                _check(cancel)
                ij, data = res
                cache.put("geometry", gkey[ij], data)
                pairs[ij] = cache_mod.from_bytes(PairGeometry, data)
                gdone[0] += 1
                progress("geometry", gdone[0], len(todo))
            needed = {k for ij in todo for k in ij}
            shared = runner.on_this_machine and runner.share_features({k: feats[k] for k in needed})
            runner.map(_task_geometry, [(i, j) if shared else (i, j, feats[i], feats[j]) for i, j in todo], got_geometry,
                       label=lambda a: f"the geometry of {photos[a[0]].name} and {photos[a[1]].name}")
        feats.clear()                    # descriptors: 4 MB a photo, not needed from here on
        cameras = None
        if params.geometry.reconstruction:
            t_cams = time.perf_counter()
            cameras = set_cameras(photo_set, params, pairs, keypoints, cache, runner, progress)
            timings["cameras_s"] = time.perf_counter() - t_cams       # part of geometry_s
        for (i, j) in list(pairs):
            pairs[(j, i)] = pairs[(i, j)].reversed()
        if cameras is not None:
            pairs = apply_reconstruction(pairs, cameras, [p.size for p in photos], keypoints, params.geometry)
            for i, why in enumerate(cameras.reasons):
                if why and cameras.n_registered:
                    _warn(f"{photos[i].path}: no camera from the set's reconstruction ({why}); "
                          "its pairs use two-view geometry")
            if not cameras.n_registered:
                _warn(f"{photo_set.root}: no reconstruction of the set ({cameras.reasons[0]}); "
                      "all pairs use two-view geometry")
        if params.geometry.two_view_max_uncertainty_frac > 0 and cameras is not None and cameras.n_registered:
            # where the set has cameras, a photo they left out must earn its pairs by certain lines;
            # without a reconstruction every pair is two-view, and the two-view tests decide alone
            pairs = uncertainty_gate(pairs, params.geometry.two_view_max_uncertainty_frac * max(
                max(p.size) for p in photos))
        if params.geometry.triplet_check:
            pairs = triplet_check(pairs, n, params.geometry.triplet_max_px)
        supports = support_sets(pairs, n)
        cap = max_supports if max_supports is not None else (8 if n > 9 else None)
        if cap is not None and cap > 0:
            supports = cap_supports(supports, pairs, cap, cameras.C if cameras is not None else None)
        timings["geometry_s"] = time.perf_counter() - t0
        if n >= 2 and not any(supports):
            reasons = sorted({pairs[(i, j)].reason.split(" (")[0] for i in range(n) for j in range(i + 1, n)})
            raise InputError(f"{photo_set.root}: no pair of photos has trustworthy geometry "
                             f"(all {n * (n - 1) // 2} pairs rejected: {'; '.join(reasons)})")
        for i, s in enumerate(supports):
            if not s:
                _warn(f"{photos[i].path}: no usable pair (no other photo has trustworthy geometry with it); "
                      "no map for this photo")

        first = on_geometry(pairs, supports, cameras) if on_geometry else None

        # 3-5. Pairs: matching maps, cached.
        t1 = time.perf_counter()
        refs = list(range(n)) if only_refs is None else sorted(set(only_refs))
        ordered = sorted(((i, j) for i in refs for j in supports[i]), key=lambda ij: ij[0] != first)
        swept = {ij for ij in ordered if _sweepable(ij, pairs[ij], cameras, params, photos[ij[0]].size)}
        cam = (lambda k: (cameras.K[k], cameras.R[k], cameras.C[k])) if cameras is not None else None
        ground = ground_plane(cameras) if swept and params.sweep.ground_planes > 0 else None
        inv = {}
        for i in {i for i, _ in swept}:
            g_i = None
            if ground is not None and ground[0] @ cameras.C[i] + ground[1] > 0:     # the camera above the ground
                g_i = (cameras.R[i] @ ground[0], float(ground[0] @ cameras.C[i] + ground[1]))
            inv[i] = reference_planes(inverse_depths((cameras.depth_range[i][0], np.inf), params.sweep.n_planes),
                                      g_i, params.sweep.ground_planes)
        pencil = _pencils(refs, supports, pairs, swept, photos, params)
        pkey = {}
        for i, j in ordered:
            g = pairs[(i, j)]
            parts = [photos[i].key, photos[j].key, params.pair_key_material(),
                     _digest_arrays(g.F if g.F is not None else np.zeros(0), g.H if g.H is not None else np.zeros(0),
                                    g.inliers_ref, g.inliers_sup), str(params.geometry.peer_homography)]
            if (i, j) in swept:
                parts += [params.sweep_key_material(), _digest_arrays(*cam(i), *cam(j), inv[i])]
            elif g.is_homography and params.sweep.enabled and params.sweep.direct_homography \
                    and g.uncertainty_px <= params.sweep.direct_max_parallax_frac * max(photos[i].size):
                parts += [params.sweep_key_material(), "aligned", str(params.patches.homography_reach_frac)]
            elif (i, j) in pencil:
                parts += [params.sweep_key_material(), "pencil", _digest_arrays(pencil[(i, j)])]
            if params.plane_cue:                      # the pair holds its plane-aligned difference too
                parts += ["plane", str(params.geometry.ransac_px), str(params.geometry.min_inliers)]
            pkey[(i, j)] = cache_mod.key("pair", *parts)

        def load(ij, data):
            if params.geometry.peer_homography:
                return cache_mod.from_bytes(PeerPair, data, float32=("diff",))
            return cache_mod.from_bytes(PairResult, data, float32=MAP_FIELDS)
        results = store if store is not None else PairStore(cache)
        todo = []
        for ij in ordered:
            decode = lambda d, ij=ij: load(ij, d)
            light = cache.load("light", pkey[ij], _decode_light)
            if light is not None and cache.has("pair", pkey[ij]):
                results.put_lazy(ij, light, pkey[ij], decode)     # read from the cache when first needed
            else:
                r = cache.load("pair", pkey[ij], decode)
                if r is None:
                    todo.append(ij)
                    continue
                results.put(ij, r, pkey[ij], decode)
                cache.put("light", pkey[ij], cache_mod.to_bytes(light_of(r)))
            if on_pair:
                on_pair(ij)
        sweep_args = lambda i, j: (cam(i), cam(j), inv[i]) if (i, j) in swept else \
            (("pencil", pencil[(i, j)]) if (i, j) in pencil else None)

        def recompute(ij):
            """A pair read lazily that the cache lost or found bad: computed again here (inline)."""
            out = []
            _Runner(rgbs, params, 1).map(_task_pair, [(*ij, pairs[ij], sweep_args(*ij))], out.append)
            cache.put("pair", pkey[ij], out[0][1])
            return load(ij, out[0][1])
        results.recompute = recompute
        pdone = [len(ordered) - len(todo)]
        progress("pairs", pdone[0], len(ordered))

        lazy = cache.root is not None and results.keep is not None     # the pairs can be read back later

        def got_pair(res):
            _check(cancel)
            ij, data, light, stored = res
            if data is None:         # the worker wrote the entry (store_in): counted here
                cache.adopt("pair", pkey[ij], stored)
            else:
                cache.put("pair", pkey[ij], data)
            cache.put("light", pkey[ij], light)
            if lazy:     # decoded when first read (a map, a viewer), not here: the main process shares the cores
                results.put_lazy(ij, _decode_light(light), pkey[ij], lambda d, ij=ij: load(ij, d))
            else:
                results.put(ij, load(ij, data), pkey[ij], lambda d, ij=ij: load(ij, d))
            if on_pair:
                on_pair(ij)
            pdone[0] += 1
            progress("pairs", pdone[0], len(ordered))
        # local workers write their pairs' entries into the cache themselves (a Dask worker may be on
        # another machine: its results come back to be cached here)
        store_in = (lambda ij: (str(cache.root), pkey[ij])) if lazy and runner.on_this_machine else (lambda ij: None)
        runner.map(_task_pair, [(i, j, pairs[(i, j)], sweep_args(i, j), store_in((i, j))) for i, j in todo], got_pair,
                   label=lambda a: f"the pair {photos[a[0]].name} -> {photos[a[1]].name}",
                   urgent=None if prefer is None else (lambda a: a[0] == prefer()))
        timings["pairs_s"] = time.perf_counter() - t1
    finally:
        runner.close()

    # 6. Set-level normalisation and aggregation; each photo's map is cached too, keyed by every
    # pair of the run (the normaliser of §3.1.2 spans them all) and every parameter, so a re-run
    # with nothing changed reads no pair at all.
    t2 = time.perf_counter()
    result = assemble(photo_set, params, pairs, supports, results, keypoints, timings, warnings, cameras)
    run_key = cache_mod.key("run", MAPS_VERSION, json.dumps(params.to_dict(), sort_keys=True, default=str),
                            *(f"{i},{j}:{pkey[(i, j)]}" for i, j in sorted(pkey)))

    def photo_map(i: int) -> np.ndarray:
        mkey = cache_mod.key("dynamic", photos[i].key, run_key, ",".join(map(str, supports[i])))
        dyn = cache.load("dynamic", mkey, lambda d: np.load(io.BytesIO(d), allow_pickle=False))
        if dyn is None or dyn.shape != tuple(photos[i].size) or dyn.dtype != np.float32:
            dyn = result.dynamic_prob(i, supports[i])
            buf = io.BytesIO()
            np.save(buf, np.ascontiguousarray(dyn, np.float32))
            cache.put("dynamic", mkey, buf.getvalue())
        return dyn

    # photos in threads, `workers` at a time: the fusion's and the smoothing's compiled passes, the
    # box filters and the big numpy passes all release the GIL (the pool's workers are idle now)
    todo_maps = [i for i in refs if supports[i]]
    n_threads = max(1, min(workers, len(todo_maps)))
    with ThreadPoolExecutor(n_threads, initializer=one_thread_per_caller if n_threads > 1 else None) as pool:
        futs = {pool.submit(photo_map, i): i for i in todo_maps}
        try:
            for k, fut in enumerate(as_completed(futs)):
                _check(cancel)
                result.dynamic[futs[fut]] = fut.result()
                progress("maps", k + 1, len(todo_maps))
        except BaseException:
            pool.shutdown(wait=True, cancel_futures=True)      # those not started never start
            raise
    timings["aggregate_s"] = time.perf_counter() - t2
    result.cache_hits = cache.hits - hits0
    result.cache_misses = cache.misses - miss0
    return result
