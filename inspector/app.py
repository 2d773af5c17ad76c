"""The web inspector: a viser app over one photo set.

One `Inspector` per process owns the set, the background computations (one `SetModel` per preset
asked for) and the shared `TermCache`. Every browser tab is a `Session` with its own GUI
(`client.gui`), scene (`client.scene`) and state; its callbacks only record the new state and
ask a `Redrawer` to draw, and the redrawer always draws the latest state, so rapid slider moves
never queue up stale redraws. A tab that disconnects stops its redrawers and is forgotten.
"""

from __future__ import annotations

import dataclasses
import io
import json
import threading
import time
import traceback
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Callable

import cv2
import numpy as np
import viser
import viser.uplot as vu

from pipeline.cache import PairCache, atomic_write_bytes
from pipeline.evaluate import THRESHOLDS
from pipeline.loading import PhotoSet
from pipeline.output import to_original
from pipeline.params import PRESETS

from . import compose, render
from .model import Score, SetModel, Settings, TermCache, gt_at_working, score, usable_supports

NO_EVIDENCE = {"neutral (ours)": "neutral", "no match (paper)": "no_match"}
BLANK = np.full((8, 8, 3), 255, np.uint8)


class Redrawer:
    """A worker thread that draws on request. Requests that arrive while it draws are merged
    into one; each draw reads the latest state, so the last value wins."""

    def __init__(self, name: str, draw: Callable[[set[str]], None]):
        self._draw = draw
        self._pending: set[str] = set()
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._idle = threading.Event()
        self._idle.set()
        self._stopped = False
        self._thread = threading.Thread(target=self._loop, name=name, daemon=True)
        self._thread.start()

    def request(self, *what: str) -> None:
        with self._lock:
            self._pending.update(what)
            self._idle.clear()
            self._wake.set()

    def _loop(self) -> None:
        while True:
            self._wake.wait()
            if self._stopped:
                return
            with self._lock:
                what, self._pending = self._pending, set()
                self._wake.clear()
            if what:
                try:
                    self._draw(what)
                except Exception:          # a tab closing mid-draw, or a bug: keep the tab alive
                    if not self._stopped:
                        traceback.print_exc()
            with self._lock:
                if not self._pending:
                    self._idle.set()

    def wait_idle(self, timeout: float = 30.0) -> bool:
        return self._idle.wait(timeout)

    def stop(self) -> None:
        self._stopped = True
        self._wake.set()
        if threading.current_thread() is not self._thread:
            self._thread.join(timeout=10)


class Inspector:
    """The app: one photo set, served to any number of tabs."""

    def __init__(self, photo_set: PhotoSet, gts: dict[str, np.ndarray], cache: PairCache, out_dir: Path,
                 host: str = "127.0.0.1", port: int = 8080, preset: str = "default", max_side: int = 640,
                 workers: int | None = None, hold: threading.Event | None = None):
        self.photo_set = photo_set
        self.hold = hold                                   # see SetModel.hold (tests only)
        self.stems = [p.stem for p in photo_set.photos]
        self.gts = gts                                     # stem -> (H, W) uint8 at original size
        self.gts_working = {s: gt_at_working(g, photo_set.photos[self.stems.index(s)].size) for s, g in gts.items()}
        self.cache = cache
        self.out_dir = out_dir
        self.max_side = max_side
        self.workers = workers
        self.default_preset = preset
        self.terms = TermCache()
        self.models: dict[str, SetModel] = {}
        self.sessions: dict[int, Session] = {}
        self._lock = threading.Lock()
        self._rerun = None
        self._recordings: list = []
        self._rerun_lock = threading.Lock()
        # Rerun work runs on one long-lived thread: the viewer process is tied to the thread that
        # started it (PR_SET_PDEATHSIG fires when that *thread* exits), and this also serialises it
        self.rerun_worker = ThreadPoolExecutor(1, thread_name_prefix="crowdcam-rerun")
        self.server = viser.ViserServer(host=host, port=port, verbose=False)
        self.server.gui.configure_theme(control_width="large", show_share_button=False, show_logo=False,
                                        titlebar_content=None)
        cam = self.server.initial_camera           # straight at the photo, up = -y (image rows go down)
        cam.position, cam.look_at, cam.up = (0.0, 0.0, -1.6), (0.0, 0.0, 0.0), (0.0, -1.0, 0.0)
        self.server.scene.set_up_direction("-y")
        self.server.on_client_connect(self._connect)
        self.server.on_client_disconnect(self._disconnect)
        self.model(preset)

    @property
    def url(self) -> str:
        host = self.server.get_host()
        return f"http://{'127.0.0.1' if host in ('0.0.0.0', '') else host}:{self.server.get_port()}/"

    def model(self, preset: str) -> SetModel:
        """The computation for a preset, started on first use."""
        with self._lock:
            m = self.models.get(preset)
            if m is None:
                m = SetModel(self.photo_set, preset, self.cache, self.max_side, self.workers, self.hold)
                m.add_listener(self._model_changed)
                self.models[preset] = m
                m.start()
            return m

    def _model_changed(self, model: SetModel) -> None:
        for s in list(self.sessions.values()):
            if s.settings.preset == model.preset:
                s.model_changed(model)

    def _connect(self, client: viser.ClientHandle) -> None:
        session = Session(self, client)
        with self._lock:
            self.sessions[client.client_id] = session
        session.start()

    def _disconnect(self, client: viser.ClientHandle) -> None:
        with self._lock:
            session = self.sessions.pop(client.client_id, None)
        if session is not None:
            session.close()

    def rerun_viewer(self):
        """The loopback Rerun web viewer, started on first use (crowdcam.rerun_web)."""
        from crowdcam.rerun_web import RerunWeb
        with self._rerun_lock:
            if self._rerun is None:
                self._rerun = RerunWeb()
            return self._rerun

    def keep_recording(self, rec) -> None:
        """Recordings stay connected while the viewer runs (disconnected before it stops)."""
        with self._rerun_lock:
            self._recordings.append(rec)

    def close(self) -> None:
        for s in list(self.sessions.values()):
            s.close()
        self.sessions.clear()
        for m in self.models.values():
            m.cancel()
        with self._rerun_lock:
            for rec in self._recordings:
                rec.disconnect()
            self._recordings.clear()
            if self._rerun is not None:
                self._rerun.close()
                self._rerun = None
        self.rerun_worker.shutdown(wait=False, cancel_futures=True)
        self.server.stop()


class Session:
    """One browser tab: its GUI, its scene, its state and its two redrawers (fast: the main view
    and per-support maps; slow: the explained pixel and the support sweep)."""

    def __init__(self, app: Inspector, client: viser.ClientHandle):
        self.app = app
        self.client = client
        self.n = len(app.stems)
        self.settings = Settings.for_preset(app.default_preset, 0, app.max_side)
        self.layers = render.Layers()
        self.unticked: dict[int, set[int]] = {}           # per reference: supports switched off
        self.ref_chosen = False                             # the user picked a reference
        self.pixel: np.ndarray | None = None
        self.dyn: np.ndarray | None = None                  # the map on screen
        self.report: compose.PixelReport | None = None
        self.score: Score | None = None
        self.ready_count = -1
        self.main_ms: list[float] = []                      # server-side redraw times of the main view
        self.events: list[tuple[str, object]] = []          # what the tab did, for tests and debugging
        self._boxes: dict[int, viser.GuiCheckboxHandle] = {}
        self._box_ref = -1
        self._fit_aspect = 0.0
        self._closed = False
        self._state_lock = threading.Lock()
        self._build()
        self.fast = Redrawer(f"tab{client.client_id}-fast", self._draw_fast)
        self.slow = Redrawer(f"tab{client.client_id}-slow", self._draw_slow)

    # ------------------------------------------------------------------ GUI
    def _build(self) -> None:
        app, gui, s = self.app, self.client.gui, self.settings
        ps = app.photo_set
        gui.main_panel.dock_right()
        gui.main_panel.set_width(400)
        self.md_title = gui.add_markdown(f"**{ps.name}** · {self.n} photos · working size {app.max_side} px")
        self.progress = gui.add_progress_bar(0.0, animated=True)
        self.md_status = gui.add_markdown("Starting…")
        self.dd_ref = gui.add_dropdown("Reference", options=app.stems, initial_value=app.stems[s.ref],
                                       hint="The photo whose moving regions are shown")
        self.dd_preset = gui.add_dropdown("Preset", options=list(PRESETS), initial_value=s.preset,
                                          hint="default: ours; paper: the paper's method unchanged")
        self.f_sup = gui.add_folder("Supports")
        with self.f_sup:
            self.md_sup = gui.add_markdown("", order=1e6)
        with gui.add_folder("Map"):
            self.sl_thr = gui.add_slider("Threshold", min=0.0, max=1.0, step=0.01, initial_value=s.threshold,
                                         hint="A pixel is dynamic when P_dynamic > threshold")
            self.sl_remap = gui.add_multi_slider("Remap range", min=0.0, max=1.0, step=0.01,
                                                 initial_value=tuple(s.remap), min_range=0.02,
                                                 hint="§3.2: P(x|I_s) is mapped to this range before the product")
            self.sl_whog = gui.add_slider("HOG weight", min=0.0, max=4.0, step=0.1, initial_value=s.w_hog,
                                          hint="Eq. 2 weight of the HOG similarity")
            self.sl_wcol = gui.add_slider("Colour weight", min=0.0, max=4.0, step=0.1, initial_value=s.w_color,
                                          hint="Eq. 2 weight of the hue-saturation histogram similarity")
            self.dd_noev = gui.add_dropdown("No evidence", options=list(NO_EVIDENCE),
                                            initial_value=_noev_label(s.no_evidence),
                                            hint="A patch with no candidate in the support counts as …")
            self.cb_refine = gui.add_checkbox("Refine (guided filter)", initial_value=s.refine)
        with gui.add_folder("View"):
            self.cb_photo = gui.add_checkbox("Photo", initial_value=True)
            self.cb_heat = gui.add_checkbox("Heat map", initial_value=True)
            self.cb_mask = gui.add_checkbox("Mask", initial_value=True)
            self.cb_gt = gui.add_checkbox("Ground truth", initial_value=bool(app.gts), disabled=not app.gts,
                                          hint="green outline" if app.gts else "this set has no ground truth")
            self.sl_opacity = gui.add_slider("Opacity", min=0.0, max=1.0, step=0.05, initial_value=0.55)
            self.btn_reset = gui.add_button("Reset view")
        self.f_eval = gui.add_folder("Evaluation", visible=bool(app.gts))
        with self.f_eval:
            self.md_eval = gui.add_markdown("")
            self.plot_eval = gui.add_uplot(
                data=(THRESHOLDS, np.zeros_like(THRESHOLDS), np.full_like(THRESHOLDS, np.nan)),
                series=(vu.Series(label="threshold"), vu.Series(label="Jaccard", stroke="#1f6feb", width=2),
                        vu.Series(label="current", stroke="#e5534b", width=2,
                                  points={"show": True, "size": 9, "fill": "#e5534b"})),
                scales={"x": vu.Scale(time=False, range=(0.0, 1.0)), "y": vu.Scale(range=(0.0, 1.0))},
                title="Jaccard vs threshold", aspect=1.8)
        with gui.add_folder("Export and Rerun"):
            self.btn_npy = gui.add_button("Download map (.npy)", hint="P_dynamic at the photo's size, float32")
            self.btn_png = gui.add_button("Download mask (.png)", hint="the mask at the current threshold")
            self.btn_save = gui.add_button("Save to output folder", hint=str(self.app.out_dir))
            self.btn_rerun = gui.add_button("Open in Rerun", hint="record this reference and open Rerun's viewer")
            self.md_export = gui.add_markdown("")

        self.panel = gui.add_panel()
        with self.panel.add_tab("Supports"):
            gui.add_markdown("P(x|I_s) per support: **blue** = a match was found (static), **red** = none "
                             "(dynamic). Greyed: switched off. F = epipolar pair, H = homography pair.")
            self.img_sup = gui.add_image(BLANK, label="per-support matching maps", format="jpeg", jpeg_quality=85)
        with self.panel.add_tab("Pixel"):
            self.md_pixel = gui.add_markdown("Click a point of the reference image to see the evidence behind it.")
            self.img_bars = gui.add_image(BLANK, label="P(x|I_s) per support", format="png", visible=False)
            self.img_evidence = gui.add_image(BLANK, label="where the pixel was searched", format="jpeg",
                                              jpeg_quality=85, visible=False)
            gui.add_markdown("Yellow: the pixel's epipolar line (or, for a homography pair, where H puts it "
                             "and the parallax search window). Green: best HOG candidate; orange: best colour "
                             "candidate, for the covering patch nearest the pixel.")
        with self.panel.add_tab("Sweep"):
            self.md_sweep = gui.add_markdown("The map as supports are added one by one (the paper's Fig. 5).")
            self.img_sweep = gui.add_image(BLANK, label="support sweep", format="jpeg", jpeg_quality=85)
            self.plot_sweep = gui.add_uplot(
                data=(np.array([1.0, 2.0]), np.full(2, np.nan), np.full(2, np.nan)),
                series=(vu.Series(label="supports"), vu.Series(label="J at threshold", stroke="#e5534b", width=2),
                        vu.Series(label="best J", stroke="#1f6feb", width=2)),
                scales={"x": vu.Scale(time=False), "y": vu.Scale(range=(0.0, 1.0))},
                title="Jaccard vs number of supports", aspect=1.8, visible=bool(self.app.gts))
        self.panel.dock_left()
        self.panel.set_width(420)

        rgb = self.app.photo_set.photos[s.ref].rgb
        self.client.scene.set_up_direction("-y")
        self.scene_img = self.client.scene.add_image("/reference", rgb, render_width=rgb.shape[1] / rgb.shape[0],
                                                     render_height=1.0, format="jpeg", jpeg_quality=88)
        self.scene_img.on_click(self._on_click)
        # a left drag on the photo must not turn it away (the camera orbits on empty space only)
        self.scene_img.on_drag("left")(lambda _ev: None)

        for h in (self.sl_thr, self.sl_remap, self.sl_whog, self.sl_wcol, self.dd_noev, self.cb_refine,
                  self.cb_photo, self.cb_heat, self.cb_mask, self.cb_gt, self.sl_opacity):
            h.on_update(self._on_control)
        self.dd_ref.on_update(self._on_ref)
        self.dd_preset.on_update(self._on_preset)
        self.btn_reset.on_click(lambda _ev: self._fit_camera())
        self.btn_npy.on_click(lambda _ev: self._download("npy"))
        self.btn_png.on_click(lambda _ev: self._download("png"))
        self.btn_save.on_click(lambda _ev: self._save())
        self.btn_rerun.on_click(lambda _ev: self.app.rerun_worker.submit(self._open_rerun_safely))
        self.client.camera.on_update(self._on_camera)

    def start(self) -> None:
        self.settings = self._current_settings()
        self._fit_camera()
        self.model_changed(self.app.model(self.settings.preset))

    def close(self) -> None:
        self._closed = True
        self.fast.stop()
        self.slow.stop()

    # ------------------------------------------------------------------ state changes (callbacks)
    def _record(self, what: str, value: object) -> None:
        self.events.append((what, value))

    def _current_settings(self) -> Settings:
        s = self.settings
        w_hog, w_col = float(self.sl_whog.value), float(self.sl_wcol.value)
        if w_hog + w_col <= 0:          # Eq. 2 needs some weight: equal weights
            w_hog = w_col = 1.0
        sups = tuple(j for j in range(self.n) if j != s.ref and j not in self.unticked.get(s.ref, set()))
        return dataclasses.replace(s, supports=sups, threshold=float(self.sl_thr.value),
                                   remap=tuple(float(v) for v in self.sl_remap.value), w_hog=w_hog, w_color=w_col,
                                   no_evidence=NO_EVIDENCE[self.dd_noev.value], refine=bool(self.cb_refine.value))

    def _on_control(self, _ev=None) -> None:
        with self._state_lock:
            old, old_layers = self.settings, self.layers
            self.settings = self._current_settings()
            self.layers = render.Layers(photo=self.cb_photo.value, heat=self.cb_heat.value, mask=self.cb_mask.value,
                                        gt=self.cb_gt.value, opacity=float(self.sl_opacity.value))
            new = self.settings
        if new == old and self.layers == old_layers:
            return
        self._record("settings", new)
        if dataclasses.replace(old, threshold=new.threshold) != new:      # the maps change
            self.fast.request("main", "supports")
            self.slow.request("sweep", "pixel")
        else:                                                             # threshold or view only
            self.fast.request("main")
            if new.threshold != old.threshold:
                self.slow.request("sweep", "pixel_text")

    def _on_ref(self, _ev=None) -> None:
        ref = self.app.stems.index(self.dd_ref.value)
        if ref == self.settings.ref:
            return
        self.ref_chosen = True
        with self._state_lock:
            self.settings = dataclasses.replace(self.settings, ref=ref)
            self.pixel, self.report = None, None
            self.settings = self._current_settings()
        self._record("ref", self.app.stems[ref])
        rgb = self.app.photo_set.photos[ref].rgb
        self.scene_img.render_width = rgb.shape[1] / rgb.shape[0]
        self._fit_camera()
        self.fast.request("status", "main", "supports")
        self.slow.request("sweep", "pixel")

    def _on_preset(self, _ev=None) -> None:
        preset = self.dd_preset.value
        if preset == self.settings.preset:
            return
        fresh = Settings.for_preset(preset, self.settings.ref, self.app.max_side)
        with self._state_lock:
            self.settings = dataclasses.replace(fresh, supports=self.settings.supports)
        self._record("preset", preset)
        # the preset's own aggregation choices (these set the widgets, whose callbacks then agree)
        self.sl_remap.value = tuple(fresh.remap)
        self.sl_whog.value, self.sl_wcol.value = fresh.w_hog, fresh.w_color
        self.dd_noev.value = _noev_label(fresh.no_evidence)
        self.cb_refine.value = fresh.refine
        self.ready_count = -1
        self.model_changed(self.app.model(preset))
        self.fast.request("main", "supports")
        self.slow.request("sweep", "pixel")

    def _on_support(self, j: int, box) -> None:
        off = self.unticked.setdefault(self.settings.ref, set())
        state, _ = self.app.model(self.settings.preset).pair_state(self.settings.ref, j)
        if state == "rejected":
            return
        if box.value:
            off.discard(j)
        else:
            off.add(j)
        self._record(f"support {self.app.stems[j]}", bool(box.value))
        self._on_control()

    def _on_click(self, ev) -> None:
        o, d = np.asarray(ev.ray_origin, np.float64), np.asarray(ev.ray_direction, np.float64)
        if abs(d[2]) < 1e-12:
            return
        p = o + d * (-o[2] / d[2])                  # the photo lies in its local z = 0 plane, centred
        h, w = self.app.photo_set.photos[self.settings.ref].size
        rw = float(self.scene_img.render_width)
        u, v = (p[0] / rw + 0.5) * w - 0.5, (p[1] + 0.5) * h - 0.5
        if not (-0.5 <= u <= w - 0.5 and -0.5 <= v <= h - 0.5):
            return
        self.pixel = np.array([np.clip(u, 0, w - 1), np.clip(v, 0, h - 1)])
        self._record("pixel", (round(float(self.pixel[0]), 1), round(float(self.pixel[1]), 1)))
        self.fast.request("main")
        self.slow.request("pixel")

    def _on_camera(self, cam) -> None:
        """Refit when the viewport's shape changes (first report, window resize)."""
        try:
            aspect = float(cam.aspect)
        except Exception:
            return
        if abs(aspect - self._fit_aspect) > 0.01 * self._fit_aspect:
            self._fit_camera()

    def _fit_camera(self) -> None:
        """Look straight at the photo, filling the viewport."""
        cam = self.client.camera
        try:
            fov, aspect = float(cam.fov), float(cam.aspect)
        except Exception:               # no camera report from the browser yet
            fov, aspect = np.deg2rad(75.0), 1.0
        self._fit_aspect = aspect
        t = np.tan(fov / 2)
        img_aspect = float(self.scene_img.render_width)
        dist = 1.06 * max(0.5 / t, 0.5 * img_aspect / (t * max(aspect, 1e-3)))
        with self.client.atomic():          # position first: it drags look_at along
            cam.position = (0.0, 0.0, -dist)
            cam.look_at = (0.0, 0.0, 0.0)
            cam.up_direction = (0.0, -1.0, 0.0)

    def model_changed(self, model: SetModel) -> None:
        """Something new is known (progress, geometry, a pair): redraw what depends on it."""
        if self._closed or model.preset != self.settings.preset:
            return
        if model.first_ref is not None and not self.ref_chosen:
            first = model.first_ref
            self.ref_chosen = True
            if first != self.settings.ref:
                self.ref_chosen = True
                self.dd_ref.value = self.app.stems[first]      # fires _on_ref
        ready = sum(1 for (i, _j) in list(model.results) if i == self.settings.ref)
        self.fast.request("status")
        if ready != self.ready_count or model.status in ("done", "failed"):
            self.ready_count = ready
            self.fast.request("main", "supports")
            self.slow.request("sweep", "pixel")

    # ------------------------------------------------------------------ drawing
    def _draw_fast(self, what: set[str]) -> None:
        model = self.app.model(self.settings.preset)
        snap = model.snapshot()
        if "status" in what:
            self._draw_status(model)
        if "main" in what:
            t0 = time.perf_counter()
            s, layers, pixel = self.settings, self.layers, self.pixel
            ref = s.ref
            stem = self.app.stems[ref]
            img, dyn = compose.main_view(snap, self.app.photo_set.photos[ref].rgb, s, layers, self.app.terms,
                                         self.app.gts_working.get(stem), pixel)
            self.scene_img.image = img
            self.main_ms = (self.main_ms + [1000 * (time.perf_counter() - t0)])[-50:]
            self.dyn = dyn
            self._draw_eval(ref, dyn, s.threshold)
        if "supports" in what and snap is not None:
            self.img_sup.image = compose.support_mosaic(snap, self.settings, self.app.terms, self.app.stems)

    def _draw_status(self, model: SetModel) -> None:
        stage, done, total = model.progress
        if model.status == "failed":
            self.progress.visible = False
            text = f"**Cannot compute the {model.preset} preset:** {model.error}"
        elif model.status == "done":
            self.progress.visible = False
            text = f"Ready: {len(model.results)} pairs ({model.preset} preset) in {model.seconds:.1f} s."
        else:
            self.progress.visible = True
            self.progress.value = 100.0 * done / total if total else 0.0
            what = {"pairs": "Matching pairs", "geometry": "Estimating geometry",
                    "features": "Finding features"}.get(stage, "Starting")
            text = f"{what}: {done} / {total} ({model.preset} preset). Maps fill in as pairs finish."
        if model.warnings:
            text += "\n\n" + "\n".join(f"- {w}" for w in model.warnings[-3:])
        self.md_status.content = text
        self._draw_support_boxes(model)

    def _draw_support_boxes(self, model: SetModel) -> None:
        """One checkbox per other photo: ready pairs can be toggled; rejected ones are disabled
        with the reason; pairs still computing are disabled until they finish."""
        ref = self.settings.ref
        if self._box_ref != ref:
            for b in self._boxes.values():
                b.remove()
            self._boxes = {}
            self._box_ref = ref
        off = self.unticked.get(ref, set())
        reasons = []
        for j in range(self.n):
            if j == ref:
                continue
            state, why = model.pair_state(ref, j)
            stem = self.app.stems[j]
            text = {"ready": stem + (" · homography" if why == "homography" else ""),
                    "computing": f"{stem} · computing…", "rejected": f"{stem} · rejected",
                    "unknown": f"{stem} · waiting"}[state]
            value = state != "rejected" and j not in off
            if state == "rejected":
                reasons.append(f"- **{stem}**: {why}")
            box = self._boxes.get(j)
            if box is None:
                with self.f_sup:
                    box = self.client.gui.add_checkbox(text, initial_value=value, disabled=state != "ready",
                                                       hint=why, order=j)
                box.on_update(lambda _ev, j=j, box=box: self._on_support(j, box))
                self._boxes[j] = box
            else:
                if box.label != text:
                    box.label = text
                if box.disabled != (state != "ready"):
                    box.disabled = state != "ready"
                if state == "rejected" and box.value:
                    box.value = False
        head = f"{len(model.supports[ref]) if model.supports else '?'} supports for {self.app.stems[ref]}."
        if model.supports is not None and not model.supports[ref]:
            head = f"**{self.app.stems[ref]} has no usable pair**: no other photo has trustworthy geometry with it."
        self.md_sup.content = head + ("\n\nRejected by the geometry test:\n" + "\n".join(reasons) if reasons else "")

    def _draw_eval(self, ref: int, dyn: np.ndarray | None, threshold: float) -> None:
        stem = self.app.stems[ref]
        gt = self.app.gts.get(stem)
        if gt is None:
            self.score = None
            if self.app.gts:
                self.md_eval.content = f"No ground truth for {stem}."
            return
        if dyn is None:
            self.score = None
            self.md_eval.content = "No map yet."
            return
        sc = score(self.app.photo_set, ref, dyn, gt, threshold)
        self.score = sc
        self.md_eval.content = (f"Jaccard at {threshold:.2f}: **{sc.at_threshold:.3f}**  \n"
                                f"Best for this image: **{sc.best:.3f}** at threshold {sc.best_threshold:.3f}")
        marker = np.full_like(THRESHOLDS, np.nan)       # one point: the current threshold
        marker[int(np.argmin(np.abs(THRESHOLDS - threshold)))] = sc.at_threshold
        self.plot_eval.data = (THRESHOLDS, sc.curve, marker)

    def _draw_slow(self, what: set[str]) -> None:
        model = self.app.model(self.settings.preset)
        snap = model.snapshot()
        if snap is None:
            return
        s = self.settings
        if "sweep" in what:
            self._draw_sweep(snap, s)
        if "pixel" in what and self.pixel is not None:
            dyn = compose.dynamic_prob(snap, s, self.app.terms)
            if dyn is None:
                self.md_pixel.content = "No support is ready for this reference yet."
                return
            self.report = compose.explain(snap, s, self.app.terms, dyn, self.pixel)
            self._record("explained", len(self.report.evidence))
            self.img_bars.image = render.bar_chart([self.app.stems[e.sup] for e in self.report.evidence],
                                                   list(self.report.values), self.report.dynamic, s.threshold)
            self.img_evidence.image = compose.evidence_tiles(snap, self.report, self.app.stems)
            self.img_bars.visible = self.img_evidence.visible = True
            what = what | {"pixel_text"}
        if "pixel_text" in what and self.report is not None:
            self.md_pixel.content = compose.report_markdown(self.report, self.app.stems, self.app.stems[s.ref],
                                                            s.threshold)

    def _draw_sweep(self, snap, s: Settings) -> None:
        view = compose.sweep(snap, s, self.app.terms)
        if not view.maps:
            self.md_sweep.content = "No support is ready for this reference yet."
            self.img_sweep.image = BLANK
            return
        gt = self.app.gts.get(self.app.stems[s.ref])
        scores = [score(self.app.photo_set, s.ref, m, gt, s.threshold) for m in view.maps] if gt is not None else None
        self.img_sweep.image = compose.sweep_mosaic(view, self.app.stems, s.threshold,
                                                    [x.at_threshold for x in scores] if scores else None)
        self.md_sweep.content = (f"P_dynamic after the first k of {len(view.maps)} supports, in support-set order "
                                 f"(the paper's Fig. 5); the last one is the main view.")
        if scores:
            k = np.arange(1, len(scores) + 1, dtype=np.float64)
            self.plot_sweep.data = (k, np.array([x.at_threshold for x in scores]), np.array([x.best for x in scores]))

    # ------------------------------------------------------------------ export and Rerun
    def _current_map(self) -> tuple[int, np.ndarray | None]:
        s = self.settings
        snap = self.app.model(s.preset).snapshot()
        dyn = compose.dynamic_prob(snap, s, self.app.terms) if snap is not None else None
        return s.ref, dyn

    def _download(self, kind: str) -> None:
        ref, dyn = self._current_map()
        stem = self.app.stems[ref]
        if dyn is None:
            self.md_export.content = "No map yet for this reference."
            return
        prob = to_original(dyn, self.app.photo_set.photos[ref])
        if kind == "npy":
            buf = io.BytesIO()
            np.save(buf, prob)
            self.client.send_file_download(f"{stem}_dynamic.npy", buf.getvalue(), save_immediately=True)
        else:
            ok, png = cv2.imencode(".png", ((prob > self.settings.threshold) * 255).astype(np.uint8))
            self.client.send_file_download(f"{stem}_mask.png", png.tobytes(), save_immediately=True)
        self._record("download", kind)

    def _save(self) -> list[Path]:
        ref, dyn = self._current_map()
        s = self.settings
        stem = self.app.stems[ref]
        if dyn is None:
            self.md_export.content = "No map yet for this reference."
            return []
        photo = self.app.photo_set.photos[ref]
        prob = to_original(dyn, photo)
        out = self.app.out_dir
        out.mkdir(parents=True, exist_ok=True)
        buf = io.BytesIO()
        np.save(buf, prob)
        files = {f"{stem}_dynamic.npy": buf.getvalue(),
                 f"{stem}_mask.png": cv2.imencode(".png", ((prob > s.threshold) * 255).astype(np.uint8))[1].tobytes(),
                 f"{stem}_overlay.jpg": cv2.imencode(".jpg", render.overlay(photo.rgb, dyn, s.threshold, self.layers,
                                                     self.app.gts_working.get(stem))[..., ::-1])[1].tobytes(),
                 f"{stem}_settings.json": json.dumps(
                     {"set": str(self.app.photo_set.root), "reference": stem,
                      "supports": [self.app.stems[j] for j in usable_supports(self.app.model(s.preset).snapshot(), s)],
                      "threshold": s.threshold, "params": s.params().to_dict()}, indent=1).encode()}
        paths = []
        for name, data in files.items():
            atomic_write_bytes(out / name, data)
            paths.append(out / name)
        self.md_export.content = f"Saved to `{out}`: " + ", ".join(f"`{p.name}`" for p in paths)
        self._record("saved", [str(p) for p in paths])
        return paths

    def _open_rerun_safely(self) -> None:
        try:
            self._open_rerun()
        except Exception as e:          # shown in the tab: the viewer failed to start, a full disk, ...
            self.md_export.content = f"Could not record to Rerun: {type(e).__name__}: {e}"

    def _open_rerun(self) -> None:
        """Record the current reference (with the explained pixel, if any) into the loopback Rerun
        viewer and link to it."""
        import rerun as rr

        from pipeline.rerun_log import log_run, make_blueprint
        self.md_export.content = "Recording to Rerun… (the viewer starts on first use)"
        s = self.settings
        snap = self.app.model(s.preset).snapshot()
        if snap is None or compose.dynamic_prob(snap, s, self.app.terms) is None:
            self.md_export.content = "No map yet for this reference."
            return
        p = s.params()
        supports = [[j for j in sup if (i, j) in snap.pair_results] for i, sup in enumerate(snap.supports)]
        supports[s.ref] = usable_supports(snap, s)
        res = dataclasses.replace(snap, params=p, supports=supports, dynamic=[None] * self.n)
        res.dynamic = [res.dynamic_prob(i, sup) if sup else None for i, sup in enumerate(supports)]
        web = self.app.rerun_viewer()
        stem = self.app.stems[s.ref]
        rec = rr.RecordingStream("crowdcam", recording_id=f"{self.app.photo_set.name}-{stem}-{int(time.time())}")
        rec.connect_grpc(web.grpc_uri)
        desc = log_run(res, rec, focus=s.ref, pixels=None if self.pixel is None else self.pixel[None], gts=self.app.gts,
                       threshold=s.threshold)
        rec.send_blueprint(make_blueprint(desc))
        rec.flush()
        self.app.keep_recording(rec)
        self._record("rerun", web.url)
        self.md_export.content = (f"Recorded {stem}: [open the Rerun viewer]({web.url}) (served on this "
                                  "machine's loopback only; the viewer takes a few seconds to load).")


def _noev_label(mode: str) -> str:
    return next(k for k, v in NO_EVIDENCE.items() if v == mode)
