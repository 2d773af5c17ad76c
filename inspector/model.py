"""What the inspector knows about a set, and how it re-aggregates fast. No viser here.

`SetModel` runs the pipeline (`run.detect_set`) for one preset in a background thread; pair
results become visible as they finish (`snapshot()`), so the page is usable while work goes on.
The reference a tab shows is `prefer`red: its pairs are the next handed to the workers, and
`reference_states` says per photo whether its map is ready.
`TermCache` keeps each support's Eq. 3 term (aggregate.support_log_odds of P(x|I_s)) keyed by
everything it depends on; a change of supports or threshold is then a sum of cached arrays, and
a change of remap or weights recomputes only the terms of the current reference.
"""

from __future__ import annotations

import dataclasses
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass
from typing import Callable

import cv2
import numpy as np

from pipeline.aggregate import dynamic_from_log_odds, support_log_odds
from pipeline.cache import PairCache
from pipeline.evaluate import jaccard, jaccard_curve, score_set, THRESHOLDS
from pipeline.loading import InputError, PhotoSet
from pipeline.output import to_original
from pipeline.params import DEFAULT_MAX_SIDE, Params, get_preset
from pipeline.run import Cancelled, SetResult, assemble, detect_set


@dataclass(frozen=True)
class Settings:
    """One browser tab's choices that the maps depend on.

    supports: enabled support indices of `ref` (admitted and finished ones are used);
    remap: §3.2 range; w_hog, w_color: Eq. 2 descriptor weights; no_evidence: "no_match" (paper)
    or "neutral"; refine: apply the preset's (or default's) spatial refinement.
    """

    preset: str = "default"
    ref: int = 0
    supports: tuple[int, ...] = ()
    threshold: float = 0.5
    remap: tuple[float, float] = (0.3, 0.7)
    w_hog: float = 2.0
    w_color: float = 1.0
    no_evidence: str = "neutral"
    refine: bool = True
    max_side: int = DEFAULT_MAX_SIDE   # the working size the set runs at (PhotoSet.working_side at most)
    changes: tuple[str, ...] = ()      # `crowdcam inspect --param` settings, applied to every preset

    @staticmethod
    def for_preset(preset: str, ref: int = 0, max_side: int = DEFAULT_MAX_SIDE,
                   changes: tuple[str, ...] = ()) -> "Settings":
        p = preset_params(preset, max_side, changes)
        return Settings(preset, ref, (), p.aggregate.threshold, tuple(p.aggregate.remap), p.descriptors.w_hog,
                        p.descriptors.w_color, p.aggregate.no_evidence, p.aggregate.refine_radius_frac > 0, max_side,
                        tuple(changes))

    def params(self) -> Params:
        """The preset with this tab's aggregation-level changes (pairs are not affected)."""
        base = preset_params(self.preset, self.max_side, self.changes)
        radius = base.aggregate.refine_radius_frac or get_preset("default").aggregate.refine_radius_frac
        return base.replace(
            descriptors=dataclasses.replace(base.descriptors, w_hog=self.w_hog, w_color=self.w_color),
            aggregate=dataclasses.replace(base.aggregate, remap=tuple(self.remap), no_evidence=self.no_evidence,
                                          threshold=self.threshold,
                                          refine_radius_frac=radius if self.refine else 0.0))


def preset_params(preset: str, max_side: int, changes: tuple[str, ...] = ()) -> Params:
    """A preset at the working size, with `crowdcam inspect --param` changes ("SECTION.FIELD=VALUE";
    Params.with_settings, which raises ValueError naming a bad one). max_side is the size the set
    runs at and wins over a change of it (the photos were loaded under that change already)."""
    return get_preset(preset).with_settings(list(changes)).replace(max_side=max_side)


class SetModel:
    """The pipeline for one preset, run in a background thread.

    status: "waiting" | "running" | "done" | "failed" | "cancelled"; progress: (stage, done,
    total); error: one-line message when failed. Listeners are called (from the worker thread)
    whenever something new is known.
    """

    def __init__(self, photo_set: PhotoSet, preset: str, cache: PairCache, max_side: int = DEFAULT_MAX_SIDE,
                 workers: int | None = None, hold: threading.Event | None = None, changes: tuple[str, ...] = ()):
        self.photo_set = photo_set
        # A gate the run waits at once the support sets are known, before any pair is computed;
        # tests hold a run "still going" with it instead of racing it (None: no gate).
        self.hold = hold
        self.params = preset_params(preset, max_side, changes).for_working_side(photo_set.working_side)
        self.preset = preset
        self.cache = cache
        self.workers = workers
        self.status = "waiting"
        self.progress: tuple[str, int, int] = ("starting", 0, 0)
        self.error: str | None = None
        self.warnings: list[str] = []
        self.pairs: dict | None = None
        self.supports: list[list[int]] | None = None
        self.cameras = None
        from pipeline.store import PairStore
        self.results = PairStore(cache)       # pair results; the most recently used stay in memory
        self.first_ref: int | None = None
        self.preferred: int | None = None     # the reference whose pairs go next (the last one a tab showed)
        self.order: list[tuple[int, int]] = []      # pairs computed by this run, in the order they finished
        self.seconds = 0.0
        self._lock = threading.Lock()
        self._listeners: list[Callable[["SetModel"], None]] = []
        self._cancel = threading.Event()
        self._thread: threading.Thread | None = None
        self._snap: tuple[int, SetResult | None] = (-1, None)

    def add_listener(self, fn: Callable[["SetModel"], None]) -> None:
        self._listeners.append(fn)

    def _notify(self) -> None:
        for fn in list(self._listeners):
            fn(self)

    def start(self) -> "SetModel":
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name=f"crowdcam-{self.preset}", daemon=True)
            self._thread.start()
        return self

    def _run(self) -> None:
        t0 = time.perf_counter()
        self.status = "running"
        self._notify()

        def progress(stage, done, total):
            self.progress = (stage, done, total)
            self._notify()

        def on_geometry(pairs, supports, cameras):
            with self._lock:
                # first_ref before supports: a reader that sees the supports (unlocked) sees it too
                self.first_ref = first_reference(supports)
                self.pairs, self.supports, self.cameras = pairs, supports, cameras
            self._notify()
            while self.hold is not None and not self.hold.wait(0.1):
                if self._cancel.is_set():
                    raise Cancelled()
            return self.first_ref

        def on_pair(ij):                     # detect_set has put it in self.results
            if self.progress[0] == "pairs":  # computed now (cached pairs arrive before the stage's progress)
                self.order.append(ij)
            self._notify()

        try:
            detect_set(self.photo_set, self.params, self.cache, workers=self.workers, progress=progress,
                       warn=self.warnings.append, on_geometry=on_geometry, on_pair=on_pair, cancel=self._cancel,
                       store=self.results, prefer=lambda: self.preferred)
            self.status = "done"
        except Cancelled:
            self.status = "cancelled"
        except InputError as e:
            self.status, self.error = "failed", str(e)
        except Exception as e:          # shown in the page, not a traceback in the terminal
            self.status, self.error = "failed", f"{type(e).__name__}: {e}"
        self.seconds = time.perf_counter() - t0
        self._notify()

    def prefer(self, ref: int) -> None:
        """Compute reference `ref`'s pairs next (those not started yet; the run's order after them)."""
        self.preferred = ref

    def reference_states(self) -> list["RefState"] | None:
        """Per photo, how far its map is (None before the support sets are known)."""
        with self._lock:
            supports = self.supports
        if supports is None:
            return None
        done = [0] * len(supports)
        for i, _j in list(self.results):
            done[i] += 1
        running = self.status in ("waiting", "running")
        nxt = self.preferred if self.preferred is not None else self.first_ref
        out = []
        for i, sups in enumerate(supports):
            k, d = len(sups), min(done[i], len(sups))
            if not k:
                state = "no map"
            elif d == k:
                state = "ready"
            elif not running:
                state = "incomplete"
            else:
                state = "computing" if d or i == nxt else "queued"
            out.append(RefState(k, d, state))
        return out

    def cancel(self) -> None:
        self._cancel.set()
        if self._thread is not None:
            self._thread.join(timeout=30)

    def pair_state(self, i: int, j: int) -> tuple[str, str]:
        """("ready" | "computing" | "rejected" | "unused" | "unknown", reason) for ordered pair
        (i, j); "unused": admitted, but not among the supports kept for photo i (the cap)."""
        with self._lock:
            if self.pairs is None:
                return "unknown", "geometry is being estimated"
            g = self.pairs.get((i, j))
            if g is None or not g.ok:
                return "rejected", g.reason if g is not None else "no geometry"
            if self.supports is not None and j not in self.supports[i]:
                return "unused", "admitted, but not among the supports kept for this photo (the best ones)"
            if (i, j) in self.results:
                return "ready", g.status
            return ("computing" if self.status in ("waiting", "running") else "unknown"), g.status

    def snapshot(self) -> SetResult | None:
        """A SetResult over the pairs finished so far (None before the support sets are known).
        The same object is returned until another pair finishes."""
        with self._lock:
            if self.supports is None:
                return None
            n = len(self.results)
            if self._snap[0] != n:
                self._snap = (n, assemble(self.photo_set, self.params, self.pairs, self.supports, self.results.view(),
                                          cameras=self.cameras))
            return self._snap[1]


@dataclass(frozen=True)
class RefState:
    """How far one photo's map is: supports (after the cap), pairs ready of them, and state:
    "ready" (all its pairs), "computing" (some ready, or next in line), "queued" (none yet),
    "no map" (no support), "incomplete" (the run stopped before its last pair)."""

    supports: int
    ready: int
    state: str


def first_reference(supports: list[list[int]]) -> int:
    """The reference shown first: the photo with the most supports (its pairs are computed first)."""
    return int(np.argmax([len(s) for s in supports])) if supports else 0


class TermCache:
    """Per-support arrays derived from a pair, keyed by what they depend on (LRU, thread-safe).

    match_prob: P(x|I_s), (h, w) float32; term: its Eq. 3 log-odds, (h, w) float32.
    """

    def __init__(self, max_items: int = 192):
        self.max_items = max_items
        self._items: OrderedDict = OrderedDict()
        self._lock = threading.Lock()

    def get(self, key, make):
        with self._lock:
            if key in self._items:
                self._items.move_to_end(key)
                return self._items[key]
        value = make()
        with self._lock:
            self._items[key] = value
            while len(self._items) > self.max_items:
                self._items.popitem(last=False)
        return value

    def match_prob(self, snap: SetResult, i: int, j: int, params: Params) -> np.ndarray:
        d, a = params.descriptors, params.aggregate
        key = ("p", id(snap.photo_set), params.preset, i, j, snap.normaliser, d.w_hog, d.w_color, a.no_evidence)
        return self.get(key, lambda: snap.match_prob(i, j, params))

    def term(self, snap: SetResult, i: int, j: int, params: Params) -> np.ndarray:
        d, a = params.descriptors, params.aggregate
        key = ("t", id(snap.photo_set), params.preset, i, j, snap.normaliser, d.w_hog, d.w_color, a.no_evidence,
               tuple(a.remap))
        return self.get(key, lambda: support_log_odds(self.match_prob(snap, i, j, params), a).astype(np.float32))

    def clear(self) -> None:
        with self._lock:
            self._items.clear()


def usable_supports(snap: SetResult, settings: Settings) -> list[int]:
    """The enabled supports of the reference whose pair result is ready, in support-set order."""
    return [j for j in snap.supports[settings.ref] if j in settings.supports and (settings.ref, j) in snap.pair_results]


def dynamic_prob(snap: SetResult, settings: Settings, terms: TermCache) -> np.ndarray | None:
    """Eq. 3 over the usable supports, then the optional refinement: (h, w) float32 in [0, 1],
    or None when no support is usable. Equals snap.dynamic_prob(ref, supports, settings.params()).
    Cached too, so that moving the threshold does not re-aggregate."""
    sups = usable_supports(snap, settings)
    if not sups:
        return None
    p = settings.params()
    i = settings.ref

    def make():
        if p.geometry.peer_homography or p.aggregate.mean_terms:
            return snap.dynamic_prob(i, sups, p)
        logit = terms.term(snap, i, sups[0], p).copy()
        for j in sups[1:]:
            logit += terms.term(snap, i, j, p)
        if not p.sweep.enabled:
            return snap.refine_dynamic(i, dynamic_from_log_odds(logit), p)
        sw = snap.sweep_log_odds(i, sups, p)          # the depth-consistent cue (pipeline/run.py)
        if sw is not None and p.sweep.weight > 0:
            logit += p.sweep.weight * sw
        a = p.aggregate
        dyn = dynamic_from_log_odds(a.calib_scale * (logit - a.calib_offset * snap.sweep_seen(i, sups, p)))
        dyn = snap.refine_dynamic(i, np.where(snap.has_evidence(i, sups, p), dyn, 0.5).astype(np.float32), p)
        return snap.with_plane_cue(i, sups, dyn, p)
    # keyed like the terms (by the normaliser, not the snapshot object, whose id can be reused), and by
    # which supports carry a depth sweep
    swept = tuple(j for j in sups if snap.is_swept(i, j))
    key = ("d", id(snap.photo_set), snap.normaliser, swept,
           dataclasses.replace(settings, threshold=0.0, supports=tuple(sups)))
    return terms.get(key, make)


@dataclass(frozen=True)
class Score:
    """Jaccard of one map against ground truth, at the photo's original size (as `crowdcam eval`).

    at_threshold: J of (P_dynamic > threshold); best: the best J over thresholds and where;
    curve: (T,) J for evaluate.THRESHOLDS."""

    at_threshold: float
    best: float
    best_threshold: float
    curve: np.ndarray


def score(photo_set: PhotoSet, i: int, dyn: np.ndarray, gt: np.ndarray, threshold: float) -> Score:
    prob = to_original(dyn, photo_set.photos[i])
    curve = jaccard_curve(prob, gt)
    k = int(np.argmax(curve))
    return Score(jaccard(prob > threshold, gt), float(curve[k]), float(THRESHOLDS[k]), curve)


@dataclass(frozen=True)
class SetBest:
    """The threshold optimised over the whole set (§4.2, "opt. per set"), scored by
    pipeline.evaluate.score_set over the maps that exist: threshold, the mean Jaccard there, and
    how many photos (with a map and ground truth) it was computed on."""

    threshold: float
    jaccard: float
    n_photos: int


def set_best_threshold(snap: SetResult, settings: Settings, gts: dict[str, np.ndarray],
                       off: dict[int, set[int]] | None = None) -> SetBest | None:
    """The set-wide best threshold for this tab's choices: every photo with ground truth and at
    least one ready support gets its map from the pipeline (SetResult.dynamic_prob) with the
    tab's aggregation settings and its supports minus those switched off (`off`: per
    reference); None when no photo has both."""
    off = off or {}
    p = settings.params()
    probs = {}
    for i, photo in enumerate(snap.photo_set.photos):
        if photo.stem not in gts:
            continue
        sups = [j for j in snap.supports[i] if (i, j) in snap.pair_results and j not in off.get(i, ())]
        if sups:
            probs[photo.stem] = to_original(snap.dynamic_prob(i, sups, p), photo)
    if not probs:
        return None
    sc = score_set(probs, gts)
    return SetBest(sc.set_threshold, sc.mean_opt_set, len(probs))


def gt_at_working(gt: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """(H, W) uint8 ground truth -> (h, w) bool 'moving' at working resolution."""
    h, w = size
    return cv2.resize((gt == 255).astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST) > 0
