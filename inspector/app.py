"""The web inspector: a viser app over one photo set.

One `Inspector` per process owns the set, the background computations (one `SetModel` per preset
asked for) and the shared `TermCache`. Every browser tab is a `Session` with its own GUI
(`client.gui`), scene (`client.scene`) and state; its callbacks only record the new state and
ask a `Redrawer` to draw, and the redrawer always draws the latest state, so rapid slider moves
never queue up stale redraws. A tab that disconnects stops its redrawers and is forgotten.
The reference is chosen in the Reference dropdown or by a click on its thumbnail in the picker
under it (picker.py; the click sets the dropdown); the reference shown is the one whose pairs the
run computes next (SetModel.prefer).

The photo stays put: viser's camera orbits on a left drag over empty space and on arrow keys.
Keys pressed on a focused control are kept from reaching the camera (a small key listener in
the page, KEYS_STAY_WITH_CONTROLS), and the server puts any turned camera back to look straight
at the photo, keeping its pan and zoom (Session._straighten).

The Geometry view (issue 10) is the one opt-in 3-D view, and it may orbit: the set's cameras as
the pipeline's reconstruction placed them (viser frustums with their photos), the sparse points,
and for a clicked reference pixel its viewing ray and its epipolar line in every support, coloured
by the pair's uncertainty (geometry_view reads SetCameras and the pairs' F / H; it estimates
nothing). It is drawn by a redrawer of its own, so the threshold's path to the picture is the same
as without it.
"""

from __future__ import annotations

import dataclasses
import html
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
from pipeline.params import DEFAULT_MAX_SIDE, PRESETS, get_preset

from . import compose, render
from . import geometry_view as gv
from pipeline.memory import limit_malloc_arenas
from .picker import Picker, Thumbnails
from .tour import Tour
from .gallery_view import GalleryView
from .side_by_side import PresetPanels
from .model import (Score, SetBest, SetModel, Settings, TermCache, gt_at_working, score, set_best_threshold,
                    usable_supports)

NO_EVIDENCE = {"no opinion, 0.5 (ours)": "neutral", "no match (paper)": "no_match"}
BLANK = np.full((8, 8, 3), 255, np.uint8)
COMPUTING = "computing…"
MAP_OPTION = "the map (reference)"
PIXEL_HINT = ("**Click a point of the photo** to see why it is marked (or not).\n\n"
              "How it works: every other photo of the scene that can be trusted (a *support*) is asked whether "
              "it shows a look-alike of the patch around the point where that point can lie. If most find one, "
              "the point is static (blue); if they do not, it has probably moved (red). The click shows each "
              "support's answer, how the answers add up, and where each support was searched.")
MAIN_WIDTH = 340            # the right (controls) panel, px
SIDE_WIDTH = 400            # the left (evidence) panel, px
KEY_WIDTH = 312             # pictures at the width they are shown at (panel less its padding)
CHART_WIDTH = 370
BRAND_RGB = (14, 70, 130)   # viser's palette of it gives buttons and active tabs (22, 108, 201): 5.2:1 on white
STRAIGHT_COS = float(np.cos(np.deg2rad(0.3)))      # a camera turned more than this is put back

PAIR_HINTS = {"ok": "epipolar pair: the point is searched along its epipolar line in this photo (§3.1); "
                           "untick to leave this photo out of the fusion (Eq. 3)",
              "homography": "homography pair: this photo is aligned to the reference by one homography (a shot "
                            "from the same spot, or a far or flat scene; ours); untick to leave it out"}
HINT_PRESET = ("default: ours (the paper's method plus a depth cue, homography pairs, colour normalisation and "
               "smoothing); paper: the paper's method unchanged; peer-homography: a simple 2-D baseline (align "
               "each photo by one homography and compare colours), for comparison.")
HINT_REMAP = ("How far one support may push the result: each P(x|I_s) is squeezed into this range (low, high) "
              "before the supports are combined, so that no single photo decides alone (§3.2; paper: 0.3, 0.7).")
HINT_NOEV = ("What a support says where it does not see the point: no opinion (0.5, ours), or no match, which "
             "reads as moving (the paper, §3.1).")
HINT_BEST_IMG = ("Set the threshold that gives this photo the highest Jaccard with its ground truth "
                 "(§4.2, optimised per image).")
PHOTO_VIEW = "Photo and map"
GEOMETRY_VIEW = "Geometry (3-D)"
HINT_VIEW = ("Photo and map: the reference with its colours; it stays straight (pan and zoom only). Geometry "
             "(3-D): the cameras as the set's reconstruction placed them and its 3-D points; drag to turn. Click "
             "the reference's picture there to see the point's viewing ray and, in every support, the line where "
             "it can lie (its epipolar line), coloured by how sure that pair's geometry is.")
THUMB_WIDTH = {True: 320, False: 192}   # a frustum's picture: the reference's larger (it is clicked)
HINT_BEST_SET = ("Set the one threshold that gives the whole set the highest mean Jaccard, over the maps that "
                 "exist (§4.2, optimised per set).")

# Controls in light grey on white (Mantine's 'dimmed', 3.3:1) read badly: a darker grey (8.6:1).
PAGE_STYLE = """<style>
:root, :root[data-mantine-color-scheme="light"] { --mantine-color-dimmed: #454c53 !important; }
.mantine-Slider-markLabel { color: #454c53 !important; }
.u-legend, .u-legend .u-value { color: #212529 !important; }
.mantine-Notification-description { color: #454c53 !important; }
</style>"""
# viser moves the camera on arrow keys (orbit) and W/A/S/D/Q/E unless a text field has the focus,
# so an arrow key on a focused slider moved both. Keys whose target is a control (anything but
# the page itself) stop at <body>: React has already handled them at its root, below it, and
# viser's camera listener on `document` never sees them. viser runs no <script> from HTML, so
# the listener is installed by an image that fails to load (once per page).
_KEYS_JS = ("if(!window.__crowdcamKeys){window.__crowdcamKeys=1;"
            "var K={ArrowUp:1,ArrowDown:1,ArrowLeft:1,ArrowRight:1,KeyW:1,KeyA:1,KeyS:1,KeyD:1,KeyQ:1,KeyE:1};"
            "document.body.addEventListener('keydown',function(e){var t=e.target;"
            "if(K[e.code]&&t&&t!==document.body&&t.tagName!=='CANVAS'){e.stopPropagation();}});}")
KEYS_STAY_WITH_CONTROLS = (f'<img src="data:," alt="" style="display:none" '
                           f'onerror="{html.escape(_KEYS_JS, quote=True)}">')


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
            if self._stopped:          # stop() may have set the wake-up this clear() just took away
                return
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

    def idle(self) -> bool:
        """Nothing to draw and nothing being drawn, now."""
        return self._idle.is_set()

    def stop(self) -> None:
        self._stopped = True
        self._wake.set()
        if threading.current_thread() is not self._thread:
            self._thread.join(timeout=10)


@dataclasses.dataclass
class GeometryScene:
    """What a tab's Geometry view has drawn. key: (preset, id of the SetCameras, reference);
    frame, depth, frustums: geometry_view's display frame, picture depth and frustums (by_photo:
    the same by photo index); root: the scene node everything hangs from; cameras: the frustum
    handles by photo; pixel_nodes: the clicked pixel's ray, lines and mark."""

    key: tuple
    ref: int
    frame: gv.DisplayFrame
    depth: float
    frustums: list[gv.Frustum]
    by_photo: dict[int, gv.Frustum]
    root: object
    cameras: dict[int, object]
    pixel_nodes: dict[str, object] = dataclasses.field(default_factory=dict)


class Inspector:
    """The app: one photo set, served to any number of tabs."""

    def __init__(self, photo_set: PhotoSet, gts: dict[str, np.ndarray], cache: PairCache, out_dir: Path,
                 host: str = "127.0.0.1", port: int = 8080, preset: str = "default", max_side: int = DEFAULT_MAX_SIDE,
                 workers: int | None = None, hold: threading.Event | None = None, changes: tuple[str, ...] = ()):
        limit_malloc_arenas()              # memory stays flat as tabs come and go (pipeline/memory.py)
        self.photo_set = photo_set
        self.hold = hold                                   # see SetModel.hold (tests only)
        self.stems = [p.stem for p in photo_set.photos]
        self.gts = gts                                     # stem -> (H, W) uint8 at original size
        self.gts_working = {s: gt_at_working(g, photo_set.photos[self.stems.index(s)].size) for s, g in gts.items()}
        self.thumbs = Thumbnails([p.rgb for p in photo_set.photos], self.stems)     # the picker's, made once
        self.cache = cache
        self.out_dir = out_dir
        self.max_side = min(max_side, photo_set.working_side)     # the size the set runs at (Params.for_working_side)
        self.workers = workers
        self.default_preset = preset
        self.changes = tuple(changes)                      # --param settings, for every preset it runs
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
                                        titlebar_content=None, brand_color=BRAND_RGB)
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
                m = SetModel(self.photo_set, preset, self.cache, self.max_side, self.workers, self.hold, self.changes)
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
        session = self.sessions.get(client.client_id)
        if session is not None:
            session.close()                 # its threads are gone before the tab is forgotten
        with self._lock:
            self.sessions.pop(client.client_id, None)

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
    """One browser tab: its GUI, its scene, its state and its two redrawers (fast: the main view,
    its key and numbers, per-support maps; slow: the explained pixel, the support sweep and the
    set-wide best threshold).

    Never stale: a change of reference or preset bumps `_epoch` and clears every plot, text and
    link of the tab at once (under `_pub`, showing "computing…" where a value is not ready); a
    draw that started before publishes nothing (it checks the epoch under the same lock). Slow
    draws also check the version of what they draw (`_versions`: "sweep", "pixel"), bumped by every
    change that makes it outdated, together with a request to draw it again."""

    def __init__(self, app: Inspector, client: viser.ClientHandle):
        self.app = app
        self.client = client
        self.n = len(app.stems)
        self.settings = Settings.for_preset(app.default_preset, 0, app.max_side, app.changes)
        self.layers = render.Layers()
        self.unticked: dict[int, set[int]] = {}           # per reference: supports switched off
        self.ref_chosen = False                             # the user picked a reference
        self.pixel: np.ndarray | None = None
        self.large: int | None = None                       # the support shown large, or None: the map
        self.dyn: np.ndarray | None = None                  # the map on screen
        self.report: compose.PixelReport | None = None
        self.pixel_parts: tuple | None = None               # (report, what the Pixel tab shows of it)
        self.sweep_shown: tuple | None = None               # (ref, SweepView, Jaccards, threshold) of the Sweep tab
        self.score: Score | None = None
        self.set_best: SetBest | None = None
        self._set_best_key_done = None
        self.notice = compose.Notice("")
        self.ready_count = -1
        self.canvas_width = 0
        self.camera_reports = 0                             # camera reports handled (tests)
        self.main_ms: list[float] = []                      # server-side redraw times of the main view
        self.events: list[tuple[str, object]] = []          # what the tab did, for tests and debugging
        self.view = "photo"                                  # the main view: "photo" or "geometry" (3-D)
        self.geo: GeometryScene | None = None               # what the Geometry view has drawn
        self.geo_lines: list[gv.SupportLine] = []           # the clicked pixel in every support (Geometry view)
        self.geo_ray: np.ndarray | None = None              # (3, 3) its viewing ray: centre, near, far (display)
        self._geo_camera: tuple | None = None               # the 3-D viewpoint to come back to
        self._geo_builds = 0
        self.hold_slow: threading.Event | None = None       # tests: a slow draw waits here before publishing
        self.slow_waiting = threading.Event()
        self._boxes: dict[int, viser.GuiCheckboxHandle] = {}
        self._box_ref = -1
        self._fit_aspect = 0.0
        self._img_aspect = 0.0
        self._closed = False
        self._state_lock = threading.Lock()
        self._pub = threading.RLock()                       # publishing to the page vs. clearing it
        self._epoch = 0                                     # reference and preset
        self._versions = {"sweep": 0, "pixel": 0}         # what the slow views were last asked to show
        self.tour: Tour | None = None                       # the guided tour, prepared links (tour.py)
        self.gallery: GalleryView | None = None             # the Gallery tab (gallery_view.py)
        self.presets: PresetPanels | None = None            # the Presets tab (side_by_side.py)
        self._build()
        self.fast = Redrawer(f"tab{client.client_id}-fast", self._draw_fast)
        self.slow = Redrawer(f"tab{client.client_id}-slow", self._draw_slow)
        self.tour = Tour(self)
        self.gallery = GalleryView(self)
        self.presets = PresetPanels(self)
        self.geo_draw = Redrawer(f"tab{client.client_id}-geometry", self._draw_geometry)

    # ------------------------------------------------------------------ GUI
    def _build(self) -> None:
        app, gui, s = self.app, self.client.gui, self.settings
        ps = app.photo_set
        has_gt = bool(app.gts)
        gui.main_panel.dock_right()
        gui.main_panel.set_width(MAIN_WIDTH)
        gui.add_html(PAGE_STYLE + KEYS_STAY_WITH_CONTROLS)
        changed = f" · changed: {', '.join(f'`{c}`' for c in app.changes)}" if app.changes else ""
        self.md_title = gui.add_markdown(f"**{ps.name}** · {self.n} photos · working size {app.max_side} px{changed}")
        self.progress = gui.add_progress_bar(0.0, animated=True)
        self.md_status = gui.add_markdown("Starting…")
        self.md_caption = gui.add_markdown(
            "**Colours: blue = static, red = moving** (P_dynamic, how likely each point moved). "
            "Red outline: marked moving" + ("; green: ground truth" if has_gt else "") +
            ". **Click a point to see why it is marked.**")
        self.img_key = gui.add_image(render.colour_key(KEY_WIDTH, "dynamic", threshold=s.threshold,
                                                       outlines=(True, has_gt)), format="png")
        self.md_notice = gui.add_markdown("", visible=False)
        self.btn_best_img_top = gui.add_button("Use this photo's best threshold", visible=False,
                                               hint=HINT_BEST_IMG)
        self.btn_best_set_top = gui.add_button("Use the set's best threshold", visible=False, hint=HINT_BEST_SET)
        self.dd_ref = gui.add_dropdown("Reference", options=app.stems, initial_value=app.stems[s.ref],
                                       hint="The photo whose moving regions are shown; its supports are the other "
                                            "photos whose geometry with it can be trusted (§3).")
        self.picker = Picker(self, app.thumbs)          # the same choice, by thumbnail (picker.py)
        self.dd_preset = gui.add_dropdown("Preset", options=list(PRESETS), initial_value=s.preset, hint=HINT_PRESET)
        self.dd_view = gui.add_dropdown("Main view", options=[PHOTO_VIEW, GEOMETRY_VIEW], initial_value=PHOTO_VIEW,
                                        hint=HINT_VIEW)
        self.img_geo_key = gui.add_image(compose.geometry_key(KEY_WIDTH), format="png", visible=False)
        self.md_geo = gui.add_markdown("", visible=False)
        self.f_sup = gui.add_folder("Supports")
        with self.f_sup:
            self.md_sup = gui.add_markdown("", order=1e6)
        with gui.add_folder("Map"):
            self.sl_thr = gui.add_slider("Threshold", min=0.0, max=1.0, step=0.005, initial_value=s.threshold,
                                         hint="A point is marked moving when P_dynamic is above this value "
                                              "(§4.2 optimises it per photo and per set).")
            self.vec_remap = gui.add_vector2("Remap range", initial_value=tuple(s.remap), min=(0.0, 0.0),
                                             max=(1.0, 1.0), step=0.01, hint=HINT_REMAP)
            self.sl_whog = gui.add_slider("HOG weight", min=0.0, max=4.0, step=0.1, initial_value=s.w_hog,
                                          hint="How much the shape comparison (HOG: histograms of gradient "
                                               "directions) counts in a support's answer (Eq. 2; paper: 2).")
            self.sl_wcol = gui.add_slider("Colour weight", min=0.0, max=4.0, step=0.1, initial_value=s.w_color,
                                          hint="How much the colour comparison (hue-saturation histograms) counts "
                                               "in a support's answer (Eq. 2; paper: 1).")
            self.dd_noev = gui.add_dropdown("No evidence", options=list(NO_EVIDENCE),
                                            initial_value=_noev_label(s.no_evidence), hint=HINT_NOEV)
            self.cb_refine = gui.add_checkbox("Smooth (guided filter)", initial_value=s.refine,
                                              hint="Smooth the map along the photo's edges (a guided filter; "
                                                   "ours, not in the paper).")
        with gui.add_folder("View"):
            self.cb_photo = gui.add_checkbox("Photo", initial_value=True, hint="the photo under the colours")
            self.cb_heat = gui.add_checkbox("Colours", initial_value=True,
                                            hint="P_dynamic as colours: blue static, red moving")
            self.cb_mask = gui.add_checkbox("Mask", initial_value=True,
                                            hint="red outline: the points above the threshold")
            self.cb_gt = gui.add_checkbox("Ground truth", initial_value=has_gt, disabled=not has_gt,
                                          hint="green outline: what really moved" if has_gt
                                          else "this set has no ground truth")
            self.sl_opacity = gui.add_slider("Opacity", min=0.0, max=1.0, step=0.05, initial_value=0.55,
                                             hint="how strongly the colours cover the photo")
            self.btn_reset = gui.add_button("Reset view", hint="look straight at the whole photo again")
        self.f_eval = gui.add_folder("Evaluation", visible=has_gt)
        with self.f_eval:
            self.md_eval = gui.add_markdown("")
            self.btn_best_img = gui.add_button("Use this photo's best threshold", disabled=True, hint=HINT_BEST_IMG)
            self.btn_best_set = gui.add_button("Use the set's best threshold", disabled=True, hint=HINT_BEST_SET)
            self.plot_eval = gui.add_uplot(
                data=(THRESHOLDS, np.full_like(THRESHOLDS, np.nan), np.full_like(THRESHOLDS, np.nan)),
                series=(vu.Series(label="threshold"), vu.Series(label="Jaccard", stroke="#1f5fbf", width=2),
                        vu.Series(label="current", stroke="#c92a2a", width=2,
                                  points={"show": True, "size": 9, "fill": "#c92a2a"})),
                scales={"x": vu.Scale(time=False, range=(0.0, 1.0)), "y": vu.Scale(range=(0.0, 1.05))},
                axes=(vu.Axis(label="threshold", stroke="#212529"), vu.Axis(label="Jaccard", stroke="#212529")),
                title="Jaccard vs threshold", aspect=1.8)
        with gui.add_folder("Export and Rerun"):
            self.btn_npy = gui.add_button("Download map (.npy)", hint="P_dynamic at the photo's size, float32")
            self.btn_png = gui.add_button("Download mask (.png)", hint="the mask at the current threshold")
            self.btn_save = gui.add_button("Save to output folder", hint=str(self.app.out_dir))
            self.btn_rerun = gui.add_button("Open in Rerun", hint="record this reference (and the clicked point) "
                                                                  "and open Rerun's viewer")
            self.md_export = gui.add_markdown("")

        self.panel = gui.add_panel()
        with self.panel.add_tab("Pixel"):
            self.md_pixel = gui.add_markdown(PIXEL_HINT)
            self.dd_large = gui.add_dropdown("Show large", options=[MAP_OPTION], initial_value=MAP_OPTION,
                                             disabled=True, hint="draw one support's evidence for the clicked "
                                                                 "point big, in the main view")
            self.img_fusion = gui.add_image(BLANK, format="png", visible=False)
            self.md_fusion = gui.add_markdown("")
            with gui.add_folder("What the numbers mean", expand_by_default=False):
                gui.add_markdown(compose.HELP)
            self.md_evidence = gui.add_markdown("")
            self.img_evidence = gui.add_image(BLANK, format="jpeg", jpeg_quality=85, visible=False)
            self.img_lines = gui.add_image(BLANK, format="png", visible=False)
        with self.panel.add_tab("Supports"):
            gui.add_markdown("Each support's answer, P(x|I_s), drawn as 1 − P: **blue** = it found a match "
                             "(static), **red** = none (moving), green = no opinion. Greyed: switched off. "
                             "F = epipolar pair, H = homography pair.")
            self.img_sup = gui.add_image(render.message(COMPUTING), format="jpeg", jpeg_quality=85)
        with self.panel.add_tab("Sweep"):
            self.md_sweep = gui.add_markdown("The map as supports are added one by one (the paper's Fig. 5).")
            self.img_sweep = gui.add_image(render.message(COMPUTING), format="jpeg", jpeg_quality=85)
            self.plot_sweep = gui.add_uplot(
                data=(np.array([1.0, 2.0]), np.full(2, np.nan), np.full(2, np.nan)),
                series=(vu.Series(label="supports"), vu.Series(label="J at threshold", stroke="#c92a2a", width=2),
                        vu.Series(label="best J", stroke="#1f5fbf", width=2)),
                scales={"x": vu.Scale(time=False, range=(1.0, 2.0)), "y": vu.Scale(range=(0.0, 1.05))},
                axes=(vu.Axis(label="supports", incrs=(1, 2, 5, 10, 20), stroke="#212529"),
                      vu.Axis(label="Jaccard", stroke="#212529")),
                title="Jaccard vs number of supports", aspect=1.8, visible=bool(self.app.gts))
        self.panel.dock_left()
        self.panel.set_width(SIDE_WIDTH)

        rgb = self.app.photo_set.photos[s.ref].rgb
        self.client.scene.set_up_direction("-y")
        self._img_aspect = rgb.shape[1] / rgb.shape[0]
        self.scene_img = self.client.scene.add_image("/reference", rgb, render_width=self._img_aspect,
                                                     render_height=1.0, format="jpeg", jpeg_quality=88)
        self.scene_img.on_click(self._on_click)
        # a left drag on the photo must not turn it away (the camera orbits on empty space only)
        self.scene_img.on_drag("left")(lambda _ev: None)

        for h in (self.sl_thr, self.vec_remap, self.sl_whog, self.sl_wcol, self.dd_noev, self.cb_refine,
                  self.cb_photo, self.cb_heat, self.cb_mask, self.cb_gt, self.sl_opacity):
            h.on_update(self._on_control)
        self.dd_ref.on_update(self._on_ref)
        self.dd_preset.on_update(self._on_preset)
        self.dd_view.on_update(self._on_view)
        self.dd_large.on_update(self._on_large)
        self.btn_reset.on_click(lambda _ev: self._fit_camera() if self.view == "photo" else self._overview_camera())
        for b in (self.btn_best_img, self.btn_best_img_top):
            b.on_click(lambda _ev: self._use_best("photo"))
        for b in (self.btn_best_set, self.btn_best_set_top):
            b.on_click(lambda _ev: self._use_best("set"))
        self.btn_npy.on_click(lambda _ev: self._download("npy"))
        self.btn_png.on_click(lambda _ev: self._download("png"))
        self.btn_save.on_click(lambda _ev: self._save())
        self.btn_rerun.on_click(lambda _ev: self._ask_rerun())
        self.client.camera.on_update(self._on_camera)

    def start(self) -> None:
        self.settings = self._current_settings()
        self._preset_controls(self.settings.preset)
        self._fit_camera()
        self.model_changed(self.app.model(self.settings.preset))

    def close(self) -> None:
        with self._pub:                 # a drawer publishing now finishes first; none publishes after
            self._closed = True
        self.fast.stop()
        self.slow.stop()
        if self.gallery is not None:
            self.gallery.close()
        if self.presets is not None:
            self.presets.close()
        self.geo_draw.stop()

    # ------------------------------------------------------------------ state changes (callbacks)
    def _record(self, what: str, value: object) -> None:
        self.events.append((what, value))
        if self.tour is not None:
            self.tour.on_event(what, value)
        if self.gallery is not None:
            self.gallery.on_event(what, value)
        if self.presets is not None:
            self.presets.on_event(what, value)

    def _current_settings(self) -> Settings:
        s = self.settings
        w_hog, w_col = float(self.sl_whog.value), float(self.sl_wcol.value)
        if w_hog + w_col <= 0:          # Eq. 2 needs some weight: equal weights
            w_hog = w_col = 1.0
        sups = tuple(j for j in range(self.n) if j != s.ref and j not in self.unticked.get(s.ref, set()))
        return dataclasses.replace(s, supports=sups, threshold=float(self.sl_thr.value),
                                   remap=_remap_range(self.vec_remap.value), w_hog=w_hog, w_color=w_col,
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
        if dataclasses.replace(old, threshold=new.threshold) != new:      # the maps change
            with self._pub:
                self._bump("sweep", "pixel")
                for b in (self.btn_best_set, self.btn_best_set_top):
                    b.label, b.disabled = f"Use the set's best threshold ({COMPUTING})", True
                if self.report is not None:          # the old numbers stay visible, marked, until redrawn
                    self.md_pixel.content = f"*Updating… ({COMPUTING})*"
                self.md_export.content = ""          # a recording or saved files of other settings
            self.fast.request("main", "supports")
            self.slow.request("sweep", "pixel", "setbest")
        else:                                                             # threshold or view only
            self.fast.request("main")
            if new.threshold != old.threshold:
                with self._pub:
                    self._bump("sweep")
                self.slow.request("sweep", "pixel_text")
        self._record("settings", new)           # last: a test that sees it finds the redraws asked for

    def _on_ref(self, _ev=None) -> None:
        ref = self.app.stems.index(self.dd_ref.value)
        if ref == self.settings.ref:
            return
        self.ref_chosen = True
        with self._state_lock:
            self.settings = dataclasses.replace(self.settings, ref=ref)
            self.settings = self._current_settings()
        self.app.model(self.settings.preset).prefer(ref)    # its pairs are computed next
        self._clear(keep_pixel=False)
        self.fast.request("status", "main", "supports")
        self.slow.request("sweep", "setbest")
        self.geo_draw.request("scene")
        self._record("ref", self.app.stems[ref])

    def _on_preset(self, _ev=None) -> None:
        preset = self.dd_preset.value
        if preset == self.settings.preset:
            return
        fresh = Settings.for_preset(preset, self.settings.ref, self.app.max_side, self.app.changes)
        with self._state_lock:
            self.settings = dataclasses.replace(fresh, supports=self.settings.supports)
        self._clear(keep_pixel=True)
        # the preset's own aggregation choices (these set the widgets, whose callbacks then agree)
        self.vec_remap.value = tuple(fresh.remap)
        self.sl_whog.value, self.sl_wcol.value = fresh.w_hog, fresh.w_color
        self.dd_noev.value = _noev_label(fresh.no_evidence)
        self.cb_refine.value = fresh.refine
        self._preset_controls(preset)
        self.ready_count = -1
        self.app.model(preset).prefer(self.settings.ref)
        self.model_changed(self.app.model(preset))
        self.fast.request("status", "main", "supports")
        self.slow.request("sweep", "pixel", "setbest")
        self.geo_draw.request("scene")
        self._record("preset", preset)

    def _preset_controls(self, preset: str) -> None:
        """The peer baseline has no Eq. 2 / Eq. 3: its remap, weights and no-evidence are off."""
        peer = get_preset(preset).geometry.peer_homography
        for h in (self.vec_remap, self.sl_whog, self.sl_wcol, self.dd_noev):
            h.disabled = peer

    def _clear(self, keep_pixel: bool) -> None:
        """Another reference or preset: every view of the old one goes at once; what is not ready
        says "computing…". The photo itself is shown right away."""
        ref = self.settings.ref
        rgb = self.app.photo_set.photos[ref].rgb
        has_gt = self.app.stems[ref] in self.app.gts
        with self._pub:
            self._epoch += 1
            self._bump("sweep", "pixel")
            if not keep_pixel:
                self.pixel = None
            self.report, self.large, self.dyn, self.score = None, None, None, None
            self.notice = compose.Notice("")
            self._show_scene(rgb)
            self.img_key.image = render.colour_key(KEY_WIDTH, "dynamic", threshold=self.settings.threshold,
                                                   outlines=(True, bool(self.app.gts)))
            self.md_notice.visible = False
            self.btn_best_img_top.visible = self.btn_best_set_top.visible = False
            self.md_pixel.content = PIXEL_HINT if self.pixel is None else f"Pixel: {COMPUTING}"
            self.dd_large.options = [MAP_OPTION]
            self.dd_large.value = MAP_OPTION
            self.dd_large.disabled = True
            self.img_fusion.visible = self.img_evidence.visible = self.img_lines.visible = False
            self.md_fusion.content = self.md_evidence.content = ""
            self.md_eval.content = COMPUTING if has_gt else (f"No ground truth for {self.app.stems[ref]}."
                                                             if self.app.gts else "")
            self.plot_eval.data = (THRESHOLDS, np.full_like(THRESHOLDS, np.nan), np.full_like(THRESHOLDS, np.nan))
            self.btn_best_img.label, self.btn_best_img.disabled = f"Use this photo's best threshold ({COMPUTING})", True
            self.img_sup.image = render.message(COMPUTING)
            self.md_sweep.content = f"The map as supports are added one by one (the paper's Fig. 5): {COMPUTING}"
            self.img_sweep.image = render.message(COMPUTING)
            k = max(2, len(self._support_list(ref)))
            self.plot_sweep.data = (np.arange(1.0, k + 1), np.full(k, np.nan), np.full(k, np.nan))
            self.plot_sweep.scales = {"x": vu.Scale(time=False, range=(1.0, float(k))),
                                      "y": vu.Scale(range=(0.0, 1.05))}
            self.md_export.content = ""
        if self.view == "photo":            # the 3-D view keeps its viewpoint (same cameras, another reference)
            self._fit_camera()

    def _support_list(self, ref: int) -> list[int]:
        m = self.app.model(self.settings.preset)
        return list(m.supports[ref]) if m.supports is not None else []

    def _on_support(self, j: int, box) -> None:
        off = self.unticked.setdefault(self.settings.ref, set())
        state, _ = self.app.model(self.settings.preset).pair_state(self.settings.ref, j)
        if state in ("rejected", "unused"):
            return
        if box.value:
            off.discard(j)
        else:
            off.add(j)
        self.fast.request("status")
        self._on_control()
        self._record(f"support {self.app.stems[j]}", bool(box.value))

    def _on_large(self, _ev=None) -> None:
        value = self.dd_large.value
        large = None if value == MAP_OPTION else self.app.stems.index(value.split(" ")[0])
        if large == self.large:
            return
        self.large = large
        self.fast.request("main")
        self._record("large", None if large is None else self.app.stems[large])

    def _use_best(self, which: str) -> None:
        """One click: the threshold that the Evaluation folder reports as best (this photo, or the
        whole set), set through the slider so that every view follows."""
        if which == "photo":
            t = self.score.best_threshold if self.score is not None else None
        else:
            t = self.set_best.threshold if self.set_best is not None else None
        if t is None:
            return
        self._record("best threshold", (which, t))
        self.sl_thr.value = float(t)               # fires _on_control

    def _on_click(self, ev) -> None:
        if self.tour is not None and self.tour.on_click(ev):      # a tour step's picture
            return
        if self.large is not None:                  # a support is shown: its pixels are not the reference's
            return
        o, d = np.asarray(ev.ray_origin, np.float64), np.asarray(ev.ray_direction, np.float64)
        if abs(d[2]) < 1e-12:
            return
        p = o + d * (-o[2] / d[2])                  # the photo lies in its local z = 0 plane, centred
        h, w = self.app.photo_set.photos[self.settings.ref].size
        rw = float(self.scene_img.render_width)
        u, v = (p[0] / rw + 0.5) * w - 0.5, (p[1] + 0.5) * h - 0.5
        if not (-0.5 <= u <= w - 0.5 and -0.5 <= v <= h - 0.5):
            return
        self._set_pixel(np.array([np.clip(u, 0, w - 1), np.clip(v, 0, h - 1)]))

    def _on_geometry_click(self, ev) -> None:
        """A click on the reference's picture in the Geometry view: the pixel under it."""
        geo = self.geo
        if geo is None or geo.ref != self.settings.ref or geo.ref not in geo.by_photo:
            return
        xy = gv.plane_to_pixel(geo.by_photo[geo.ref], self.app.photo_set.photos[geo.ref].size, ev.ray_origin,
                               ev.ray_direction)
        if xy is not None:
            self._set_pixel(xy)

    def _set_pixel(self, xy: np.ndarray) -> None:
        """Explain working pixel xy of the reference (from either view)."""
        self.pixel = np.asarray(xy, np.float64)
        with self._pub:
            self._bump("pixel")
            self.md_pixel.content = f"**Pixel ({self.pixel[0]:.0f}, {self.pixel[1]:.0f})**: {COMPUTING}"
        self.fast.request("main")
        self.slow.request("pixel")
        self.geo_draw.request("ray")
        self._record("pixel", (round(float(self.pixel[0]), 1), round(float(self.pixel[1]), 1)))

    def pixel_to_canvas(self, u: float, v: float) -> tuple[float, float]:
        """Where working pixel (u, v) of the reference appears in the canvas, as fractions of its
        width and height, from the camera the browser last reported (for tests and screenshots)."""
        h, w = self.app.photo_set.photos[self.settings.ref].size
        rw = float(self.scene_img.render_width)
        return self.world_to_canvas(np.array([((u + 0.5) / w - 0.5) * rw, (v + 0.5) / h - 0.5, 0.0]))

    def world_to_canvas(self, X: np.ndarray) -> tuple[float, float]:
        """Where scene point X appears in the canvas, as fractions of its width and height (the
        camera's reported image size is the render size, which viser may scale down from the
        canvas's CSS size), from the camera the browser last reported."""
        cam = self.client.camera
        R = _quat_to_matrix(np.asarray(cam.wxyz, np.float64))           # camera -> world, OpenCV axes
        x = R.T @ (np.asarray(X, np.float64) - np.asarray(cam.position, np.float64))
        f = 0.5 * cam.image_height / np.tan(cam.fov / 2)
        return 0.5 + f * x[0] / x[2] / cam.image_width, 0.5 + f * x[1] / x[2] / cam.image_height

    # ------------------------------------------------------------------ the Geometry view (3-D)
    def _on_view(self, _ev=None) -> None:
        view = "geometry" if self.dd_view.value == GEOMETRY_VIEW else "photo"
        if view == self.view:
            return
        photo = view == "photo"
        if photo and self.geo is not None:      # come back to this viewpoint
            cam = self.client.camera
            self._geo_camera = (self.geo.key, tuple(cam.position), tuple(cam.look_at))
        with self._pub:
            self.view = view
            self.scene_img.visible = photo
            if self.geo is not None:
                self.geo.root.visible = not photo
            self.md_caption.visible = self.img_key.visible = photo
            self.md_geo.visible = self.img_geo_key.visible = not photo
            self._draw_notice(self.notice, self.score)
        if photo:
            self._fit_camera()
        else:
            self.md_geo.content = f"Geometry: {COMPUTING}"
            geo = self.geo
            if geo is not None and geo.key[0] == self.settings.preset:    # drawn before: its viewpoint again
                if self._geo_camera is not None and self._geo_camera[0] == geo.key:
                    with self.client.atomic():
                        self.client.camera.position, self.client.camera.look_at = self._geo_camera[1:]
                        self.client.camera.up_direction = (0.0, -1.0, 0.0)
                else:
                    self._overview_camera()
            self.geo_draw.request("scene", "ray")
        self._record("view", view)

    def set_view(self, view: str) -> None:
        """Show the main view `view` ("photo" or "geometry") as the Main view control does (the
        tour uses it: its step 1 shows the cameras in 3-D)."""
        label = GEOMETRY_VIEW if view == "geometry" else PHOTO_VIEW
        if self.dd_view.value != label:
            self.dd_view.value = label          # fires _on_view
        elif view != self.view:
            self._on_view()

    def _overview_camera(self) -> None:
        if self.geo is None:
            return
        try:
            fov, aspect = float(self.client.camera.fov), float(self.client.camera.aspect)
        except Exception:               # no camera report from the browser yet
            fov, aspect = np.deg2rad(75.0), 1.0
        position, look_at = gv.overview_camera(self.geo.frustums, fov, aspect)
        with self.client.atomic():          # position first: it drags look_at along
            self.client.camera.position = tuple(position)
            self.client.camera.look_at = tuple(look_at)
            self.client.camera.up_direction = (0.0, -1.0, 0.0)

    def _draw_geometry(self, what: set[str]) -> None:
        """The Geometry view, when it is shown: the scene again when the cameras, the reference or
        the preset changed, then the clicked pixel's ray and lines."""
        if self.view != "geometry" or self._closed:
            return
        s = self.settings
        snap = self.app.model(s.preset).snapshot()
        cams = snap.cameras if snap is not None else None
        if snap is None or cams is None or not cams.n_registered:
            if self.geo is not None:
                self.geo.root.visible = False
            if snap is None:
                text = f"Geometry: {COMPUTING}"
            elif not snap.params.geometry.reconstruction:
                text = (f"**No cameras in the `{s.preset}` preset**: it uses each pair's own two-view geometry "
                        "(the paper's method) or one homography per pair. Choose the `default` preset to see the "
                        "set's cameras in 3-D.")
            else:
                text = (f"**No camera could be placed for {self.app.photo_set.name}**"
                        + (f" ({cams.reasons[0]})" if cams is not None and cams.reasons else "")
                        + ": every pair uses its own two-view geometry.")
            with self._pub:
                if self.view == "geometry" and not self._closed:
                    self.md_geo.content = text
            self._record("geometry", None)
            return
        key = (s.preset, id(cams), s.ref)
        if self.geo is None or self.geo.key != key:
            self._build_geometry(snap, key)
        self._draw_geometry_pixel(snap)
        if self.tour is not None:           # the tour's step 1 is this view: its picture is sent
            self.tour.shown_3d()

    def _build_geometry(self, snap, key: tuple) -> None:
        cams, ref = snap.cameras, key[2]
        photos = self.app.photo_set.photos
        sizes = [p.size for p in photos]
        frame = gv.display_frame(cams)
        depth = gv.frustum_depth(frame, cams)
        frustum_list = gv.frustums(cams, sizes, frame, depth, ref)
        supports = snap.supports[ref]
        scene = self.client.scene
        old, first = self.geo, self.geo is None or self.geo.key[:2] != key[:2]
        self._geo_builds += 1                 # a new name each time: the old scene is removed after
        root = scene.add_frame(f"/geometry_{self._geo_builds}", show_axes=False, visible=self.view == "geometry")
        points, colours = gv.scene_points(cams, frame)
        scene.add_point_cloud(f"{root.name}/points", points, colours, point_size=0.006,
                              point_shape="rounded")
        handles = {}
        for f in frustum_list:
            k = f.photo
            # frames say the photo's role; the uncertainty colours are the lines' alone, so that a
            # line reads against its frame
            g = snap.pairs.get((ref, k))
            if k == ref:
                colour = gv.REFERENCE_RGB
            elif k in supports and g is not None and g.ok:
                colour = gv.SUPPORT_RGB
            else:
                colour = gv.OTHER_RGB
            h = scene.add_camera_frustum(f"{root.name}/cameras/{k}", fov=f.fov, aspect=f.aspect, scale=1.0,
                                         thickness=4.0 if k == ref else 2.5, thickness_units="screen", color=colour,
                                         image=render.fit(photos[k].rgb, THUMB_WIDTH[k == ref]), format="jpeg",
                                         jpeg_quality=85, wxyz=viser.transforms.SO3.from_matrix(f.rotation).wxyz,
                                         position=f.position)
            h.scale = f.depth / h.compute_canonical_frustum_size()[2]      # the picture at z = depth
            if k == ref:
                h.on_click(self._on_geometry_click)
            handles[k] = h
        # one label per camera place, above its first picture (shots from one spot share a place)
        for n, group in enumerate(gv.label_groups(frustum_list, ref)):
            f = group[0]
            h, w = sizes[f.photo]
            top = gv.pixel_on_plane(f, sizes[f.photo], np.array([[w / 2, -0.1 * h]]))[0]
            names = [self.app.stems[g.photo] + (" (reference)" if g.photo == ref else "") for g in group]
            scene.add_label(f"{root.name}/labels/{n}", " · ".join(names), position=top, anchor="bottom-center",
                            font_screen_scale=0.8)
        geo = GeometryScene(key, ref, frame, depth, frustum_list, {f.photo: f for f in frustum_list}, root, handles)
        with self._pub:
            self.geo = geo
            if old is not None:
                old.root.remove()
            self.geo_lines, self.geo_ray = [], None
        if self._geo_camera is not None and self._geo_camera[0] == key and not first:
            with self.client.atomic():
                self.client.camera.position, self.client.camera.look_at = self._geo_camera[1:]
        elif first or self._geo_camera is None or self._geo_camera[0][:2] != key[:2]:
            self._overview_camera()
        self._record("geometry scene", (self.app.stems[ref], len(frustum_list)))

    def _draw_geometry_pixel(self, snap) -> None:
        """The clicked pixel in 3-D: its viewing ray (from the reference's centre; thick over the
        scene's depth range) and where it can lie in every support, on the supports' pictures."""
        geo, pixel, ref = self.geo, self.pixel, self.settings.ref
        cams = snap.cameras
        scene = self.client.scene
        sizes = [p.size for p in self.app.photo_set.photos]
        supports = snap.supports[ref]
        lines = gv.support_lines(snap.pairs, ref, supports, sizes, pixel) if pixel is not None else []
        text = compose.geometry_markdown(self.app.photo_set.name, self.app.stems, ref, cams, snap.pairs, supports,
                                         lines)
        with self._pub:
            if self.geo is not geo or self._closed:
                return
            for name in ("ray", "lines", "mark"):
                if name in geo.pixel_nodes:
                    geo.pixel_nodes.pop(name).remove()
            self.geo_lines, self.geo_ray = lines, None
            if pixel is not None and ref in geo.by_photo:
                ray = gv.viewing_ray(cams, geo.frame, ref, pixel)
                # thin from the camera to the scene's near depth, thick across the scene's depth range
                geo.pixel_nodes["ray"] = scene.add_line_segments(
                    f"{geo.root.name}/ray", np.stack([ray[:2], ray[1:]]),
                    np.array([[gv.OTHER_RGB] * 2, [gv.REFERENCE_RGB] * 2], np.uint8), thickness=4.0,
                    thickness_units="screen")
                segments, colours = gv.support_segments(lines, geo.by_photo, sizes)
                if len(segments):
                    geo.pixel_nodes["lines"] = scene.add_line_segments(f"{geo.root.name}/lines", segments, colours,
                                                                       thickness=5.0, thickness_units="screen")
                h, w = sizes[ref]
                mark = gv.pixel_on_plane(geo.by_photo[ref], sizes[ref], gv.cross(pixel, 0.03 * max(h, w)).reshape(-1, 2),
                                         inset=0.01).reshape(-1, 2, 3)
                geo.pixel_nodes["mark"] = scene.add_line_segments(f"{geo.root.name}/mark", mark, (255, 255, 255),
                                                                  thickness=3.0, thickness_units="screen")
                self.geo_ray = ray
            self.md_geo.content = text
        self._record("geometry pixel", None if pixel is None else (tuple(np.round(pixel, 1)), len(lines)))

    # ------------------------------------------------------------------ the camera
    def _on_camera(self, cam) -> None:
        """The photo stays put: whatever turned the camera (a drag on empty space, arrow keys on
        the canvas), it is put back to look straight at the photo, keeping pan and zoom. Also
        refits when the viewport's shape changes (first report, window resize)."""
        try:
            aspect = float(cam.aspect)
            self.canvas_width = int(cam.image_width)
        except Exception:
            return
        if self.view == "geometry":         # the opt-in 3-D view: turning it is the point
            self.camera_reports += 1
            return
        if not self._straighten(cam) and abs(aspect - self._fit_aspect) > 0.01 * self._fit_aspect:
            self._fit_camera()
        if self.tour is not None:           # a tour step's picture is laid out for the canvas's shape
            self.tour.on_canvas(aspect)
        self.camera_reports += 1

    def _straighten(self, cam) -> bool:
        pos, look = np.asarray(cam.position, np.float64), np.asarray(cam.look_at, np.float64)
        up = np.asarray(cam.up_direction, np.float64)
        f = look - pos
        dist = float(np.linalg.norm(f))
        if dist < 1e-9 or np.linalg.norm(up) < 1e-9:
            return False
        drifted = abs(look[2]) > 1e-3
        if drifted:
            if f[2] / dist > 0.99 and abs(look[2]) < 0.05 * dist:
                # the photo view's own camera, nearly straight, its look_at a little off the photo's
                # plane: a report made between the position and the look_at that straightening sets
                # (the position drags look_at along) while the user still drags. Put it back where
                # its ray meets the plane, keeping the zoom: a refit here lost the user's zoom, now
                # and then, under load (the browser test's zoom kept after a drag).
                look = pos + f * (-pos[2] / f[2])
            else:
                # not a photo-view camera (pan and orbit keep look_at on the photo's plane, z = 0): a
                # late report of the 3-D view's camera (the tour's step 1, the Geometry view) arriving
                # after the switch back. Straightening it would keep its look_at, off the photo: refit.
                self._fit_camera()
                self._record("camera refitted", None)
                return True
        straight = f[2] / dist > STRAIGHT_COS and float(up @ (0.0, -1.0, 0.0)) / np.linalg.norm(up) > STRAIGHT_COS
        if straight and not drifted:
            return False
        with self.client.atomic():          # position first: it drags look_at along
            cam.position = (look[0], look[1], look[2] - dist)
            cam.look_at = (look[0], look[1], look[2])
            cam.up_direction = (0.0, -1.0, 0.0)
        self._record("camera straightened", (round(float(np.degrees(np.arccos(np.clip(f[2] / dist, -1, 1)))), 1)))
        return True

    def _fit_camera(self) -> None:
        """Look straight at the picture in the main view, filling the viewport."""
        cam = self.client.camera
        try:
            fov, aspect = float(cam.fov), float(cam.aspect)
        except Exception:               # no camera report from the browser yet
            fov, aspect = np.deg2rad(75.0), 1.0
        self._fit_aspect = aspect
        dist = self.fit_distance(fov, aspect)
        with self.client.atomic():          # position first: it drags look_at along
            cam.position = (0.0, 0.0, -dist)
            cam.look_at = (0.0, 0.0, 0.0)
            cam.up_direction = (0.0, -1.0, 0.0)

    def fit_distance(self, fov: float, aspect: float) -> float:
        """The camera's distance from the picture (height 1, width render_width) at which it fills a
        viewport of this vertical field of view (radians) and aspect (width / height), with a 4 % margin."""
        t = np.tan(fov / 2)
        img_aspect = float(self.scene_img.render_width)
        return 1.04 * max(0.5 / t, 0.5 * img_aspect / (t * max(aspect, 1e-3)))

    def _show_scene(self, img: np.ndarray) -> bool:
        """Put a picture in the main view; True when its shape changed (the camera is refitted)."""
        aspect = img.shape[1] / img.shape[0]
        changed = abs(aspect - self._img_aspect) > 1e-6
        if changed:
            self._img_aspect = aspect
            self.scene_img.render_width = aspect
        self.scene_img.image = img
        return changed

    def model_changed(self, model: SetModel) -> None:
        """Something new is known (progress, geometry, a pair): redraw what depends on it."""
        if self._closed or model.preset != self.settings.preset:
            return
        if model.first_ref is not None and not self.ref_chosen:
            first = model.first_ref
            self.ref_chosen = True
            if first != self.settings.ref:
                self.dd_ref.value = self.app.stems[first]      # fires _on_ref
        ready = sum(1 for (i, _j) in list(model.results) if i == self.settings.ref)
        self.fast.request("status")
        if self.view == "geometry" and (self.geo is None or self.geo.key[1] != id(model.cameras)):
            self.geo_draw.request("scene")        # the cameras became known (or the preset changed)
        if ready != self.ready_count or model.status in ("done", "failed"):
            self.ready_count = ready
            self.fast.request("main", "supports")
            self.slow.request("sweep", "pixel", "setbest")

    # ------------------------------------------------------------------ drawing
    def _large_width(self) -> int:
        return int(np.clip(self.canvas_width or 900, 480, 1600))

    def _draw_fast(self, what: set[str]) -> None:
        epoch = self._epoch
        model = self.app.model(self.settings.preset)
        snap = model.snapshot()
        if "status" in what:
            self._draw_status(model, epoch)
        if "main" in what:
            t0 = time.perf_counter()
            s, layers, pixel, large, report = self.settings, self.layers, self.pixel, self.large, self.report
            ref = s.ref
            stem = self.app.stems[ref]
            gt = self.app.gts.get(stem)
            img, dyn = compose.main_view(snap, self.app.photo_set.photos[ref].rgb, s, layers, self.app.terms,
                                         self.app.gts_working.get(stem), pixel)
            if large is not None and report is not None and report.ref == ref and \
                    large in [e.sup for e in report.evidence]:
                img = compose.large_view(snap, report, large, self.app.stems, self._large_width())
            if self.tour is not None:       # a tour step draws its own picture (the plain one when off)
                img = self.tour.picture(snap, img, dyn)
            with self._pub:                 # the picture first, then its key and numbers
                if epoch != self._epoch:
                    return
                if self._show_scene(img) and self.view == "photo":
                    self._fit_camera()      # (the 3-D view keeps its own camera)
                if self.tour is not None:
                    self.tour.shown()
                self.main_ms = (self.main_ms + [1000 * (time.perf_counter() - t0)])[-50:]
                self.dyn = dyn
            n_sup = len(usable_supports(snap, s)) if snap is not None else 0
            notice = compose.map_notice(stem, dyn, s.threshold, n_sup)
            sc = score(self.app.photo_set, ref, dyn, gt, s.threshold) if gt is not None and dyn is not None else None
            key = render.colour_key(KEY_WIDTH, "dynamic", None if dyn is None else (float(dyn.min()), float(dyn.max())),
                                    s.threshold, outlines=(layers.mask, bool(self.app.gts) and layers.gt))
            with self._pub:
                if epoch != self._epoch:
                    return
                self.score, self.notice = sc, notice
                self.img_key.image = key
                self._draw_notice(notice, sc)
                self._draw_eval(ref, dyn, s.threshold, sc)
        if "supports" in what and snap is not None:
            img = compose.support_mosaic(snap, self.settings, self.app.terms, self.app.stems)
            with self._pub:
                if epoch == self._epoch:
                    self.img_sup.image = img

    def _draw_notice(self, notice: compose.Notice, sc: Score | None) -> None:
        text = notice.text
        if self.large is not None:
            text = (f"Showing the support **{self.app.stems[self.large]}** large (Pixel tab, *Show large*: "
                    "choose *the map* to go back).") + ("\n\n" + text if text else "")
        self.md_notice.content = text
        photo = self.view == "photo"
        self.md_notice.visible = bool(text) and photo
        offer = (notice.empty or notice.doubtful) and self.app.gts.get(self.app.stems[self.settings.ref]) is not None
        self.btn_best_img_top.visible = offer and sc is not None and photo
        self.btn_best_set_top.visible = offer and self.set_best is not None and photo
        if sc is not None:
            self.btn_best_img_top.label = f"Use this photo's best threshold ({sc.best_threshold:.3f})"

    def _draw_status(self, model: SetModel, epoch: int) -> None:
        stage, done, total = model.progress
        if model.status == "failed":
            text = f"**Cannot compute the {model.preset} preset:** {model.error}"
        elif model.status == "done":
            text = f"Ready: {len(model.results)} pairs ({model.preset} preset) in {model.seconds:.1f} s."
        else:
            what = {"pairs": "Matching pairs", "geometry": "Estimating geometry",
                    "features": "Finding features", "screen": "Choosing which pairs to compare",
                    "cameras": "Reconstructing the cameras",
                    "maps": "Making each photo's map"}.get(stage, "Starting")
            tail = "Each map shows as soon as it is made." if stage == "maps" else "Maps fill in as pairs finish."
            text = f"{what}: {done} / {total} ({model.preset} preset). {tail}"
        # photos without a usable pair in one line, by name (the picker marks them "no map"); with
        # 100 photos their warnings, a full path each, filled the panel's top
        others = [w for w in model.warnings if "no usable pair" not in w]
        lines = [f"- {w}" for w in others[-3:]]
        sups = model.supports
        lonely = [self.app.stems[i] for i, sp in enumerate(sups) if not sp] if sups is not None else []
        if lonely:
            lines.append(f"- no usable pair, so no map (no other photo has trustworthy geometry with it): "
                         f"{', '.join(lonely)}")
        if lines:
            text += "\n\n" + "\n".join(lines)
        with self._pub:
            if epoch != self._epoch:
                return
            self.progress.visible = model.status not in ("done", "failed")
            if self.progress.visible:
                self.progress.value = 100.0 * done / total if total else 0.0
            self.md_status.content = text
            self._draw_support_boxes(model)
            if self.picker.draw(model):
                self._record("picker", self.settings.ref)

    def _draw_support_boxes(self, model: SetModel) -> None:
        """One checkbox per support of the reference: ready pairs can be toggled; pairs still
        computing are disabled until they finish. The other photos are listed, not boxed (with
        100 photos, 91 boxes that can never be ticked were a wall of the panel and 99 GUI elements
        made again on every change of reference): the rejected ones with the geometry test's
        reason (grouped by reason when there are many), those the cap left out by name. The head
        counts what is on: "6 of 9 supports on"."""
        ref = self.settings.ref
        if self._box_ref != ref:
            for b in self._boxes.values():
                b.remove()
            self._boxes = {}
            self._box_ref = ref
        off = self.unticked.get(ref, set())
        reasons: dict[str, list[str]] = {}
        unused = []
        for j in range(self.n):
            if j == ref:
                continue
            state, why = model.pair_state(ref, j)
            stem = self.app.stems[j]
            if state == "rejected":
                reasons.setdefault(why, []).append(stem)
                continue
            if state == "unused":
                unused.append(stem)
                continue
            if model.supports is None:          # nothing to box before the support sets are known
                continue
            hint = {"ready": PAIR_HINTS.get(why, why), "computing": "this pair is being computed",
                    "unknown": "waiting for its pair"}[state]
            text = {"ready": stem + (" · homography" if why == "homography" else ""),
                    "computing": f"{stem} · computing…", "unknown": f"{stem} · waiting"}[state]
            value = j not in off
            box = self._boxes.get(j)
            if box is None:
                with self.f_sup:
                    box = self.client.gui.add_checkbox(text, initial_value=value, disabled=state != "ready",
                                                       hint=hint, order=j)
                box.on_update(lambda _ev, j=j, box=box: self._on_support(j, box))
                self._boxes[j] = box
            else:
                if box.label != text:
                    box.label = text
                if box.hint != hint:
                    box.hint = hint
                if box.disabled != (state != "ready"):
                    box.disabled = state != "ready"
        stem = self.app.stems[ref]
        if model.supports is None:
            head = f"Supports for {stem}: {COMPUTING}"
        elif not model.supports[ref]:
            head = f"**{stem} has no usable pair**: no other photo has trustworthy geometry with it."
        else:
            sups = model.supports[ref]
            on = [j for j in sups if j not in off]
            ready = [j for j in on if (ref, j) in model.results]
            head = f"**{len(on)} of {len(sups)} supports on** for {stem}"
            if len(ready) < len(on):
                head += f" ({len(on) - len(ready)} still computing)"
            head += "."
        if unused:
            head += f"\n\nNot used (only the best {len(model.supports[ref])} are kept): {', '.join(unused)}."
        self.md_sup.content = head + rejected_markdown(reasons, self.app.stems)

    def _draw_eval(self, ref: int, dyn: np.ndarray | None, threshold: float, sc: Score | None) -> None:
        stem = self.app.stems[ref]
        nan = np.full_like(THRESHOLDS, np.nan)
        if stem not in self.app.gts:
            if self.app.gts:
                self.md_eval.content = f"No ground truth for {stem}."
                self.plot_eval.data = (THRESHOLDS, nan, nan)
            self.btn_best_img.label, self.btn_best_img.disabled = "Use this photo's best threshold", True
            return
        if dyn is None or sc is None:
            self.md_eval.content = f"No map yet for {stem}."
            self.plot_eval.data = (THRESHOLDS, nan, nan)
            self.btn_best_img.label, self.btn_best_img.disabled = "Use this photo's best threshold", True
            return
        text = (f"{stem}: Jaccard at {threshold:.3f}: **{sc.at_threshold:.3f}**  \n"
                f"Best for this photo: **{sc.best:.3f}** at threshold **{sc.best_threshold:.3f}**")
        if self.set_best is not None:
            text += (f"  \nBest for the whole set ({self.set_best.n_photos} photos, mean Jaccard "
                     f"{self.set_best.jaccard:.3f}): threshold **{self.set_best.threshold:.3f}**")
        self.md_eval.content = text
        self.btn_best_img.label = f"Use this photo's best threshold ({sc.best_threshold:.3f})"
        self.btn_best_img.disabled = False
        marker = nan.copy()                         # one point: the current threshold
        marker[int(np.argmin(np.abs(THRESHOLDS - threshold)))] = sc.at_threshold
        self.plot_eval.data = (THRESHOLDS, sc.curve, marker)

    def _bump(self, *views: str) -> None:
        """What these slow views were drawing is outdated (call under _pub, with a redraw asked for)."""
        for v in views:
            self._versions[v] += 1

    def _publishable(self, epoch: int, view: str, version: int) -> bool:
        return epoch == self._epoch and version == self._versions[view] and not self._closed

    def _draw_slow(self, what: set[str]) -> None:
        epoch, versions = self._epoch, dict(self._versions)
        model = self.app.model(self.settings.preset)
        snap = model.snapshot()
        if snap is None:
            return
        s = self.settings
        if "sweep" in what:
            self._draw_sweep(snap, s, epoch, versions["sweep"])
        if "setbest" in what:
            self._draw_set_best(snap, s, epoch)
        if "pixel" in what and self.pixel is not None:
            pixel = self.pixel
            dyn = compose.dynamic_prob(snap, s, self.app.terms)
            if dyn is None:
                with self._pub:
                    if self._publishable(epoch, "pixel", versions["pixel"]):
                        self.md_pixel.content = "No support is ready for this reference yet."
                return
            report = compose.explain(snap, s, self.app.terms, dyn, pixel, self.app.stems)
            parts = self._pixel_parts(snap, report, s)
            if self.hold_slow is not None:          # tests: a draw held here while the tab changes
                self.slow_waiting.set()
                self.hold_slow.wait(60)
            with self._pub:
                if not self._publishable(epoch, "pixel", versions["pixel"]):
                    return
                self.report = report
                self._publish_pixel(report, parts)
            self._record("explained", len(report.evidence))
            if self.large is not None:
                self.fast.request("main")
            what = what - {"pixel_text"}
        if "pixel_text" in what and self.report is not None and self.report.ref == s.ref and \
                self.pixel is not None and np.array_equal(self.report.xy, self.pixel):
            report = dataclasses.replace(self.report, fusion=dataclasses.replace(
                self.report.fusion, threshold_at=compose.threshold_at(self.report.fusion, s.threshold)))
            chart = self._fusion_chart(report)
            with self._pub:
                if self._publishable(epoch, "pixel", versions["pixel"]):
                    self.md_pixel.content = compose.verdict_markdown(report, self.app.stems[s.ref], s.threshold)
                    self.img_fusion.image = chart

    def _fusion_chart(self, report: compose.PixelReport) -> np.ndarray:
        f = report.fusion
        if f.method == "votes":
            rows = [render.VoteRow(r.name, r.vote, r.total, neutral=r.kind == "mean") for r in f.rows]
            rows += [render.VoteRow(name, vote, total, neutral=neutral) for name, vote, total, neutral in
                     compose.after_the_sum(f)]
            return render.fusion_chart(rows, f.threshold_at, f.p_map, CHART_WIDTH)
        return render.value_bars([r.name for r in f.rows], [r.p for r in f.rows], f.p_map, self.settings.threshold,
                                 CHART_WIDTH)

    def _pixel_parts(self, snap, report: compose.PixelReport, s: Settings) -> dict:
        kinds = {e.kind for e in report.evidence}
        swept = any(e.strip is not None for e in report.evidence)
        return {"chart": self._fusion_chart(report),
                "tiles": compose.evidence_tiles(snap, report, self.app.stems),
                "legend": compose.lines_legend(2 * compose.EVIDENCE_TILE + 4, kinds, swept, 12),
                "verdict": compose.verdict_markdown(report, self.app.stems[s.ref], s.threshold),
                "fusion": compose.fusion_markdown(report),
                "evidence": compose.evidence_markdown(report, self.app.stems)}

    def _publish_pixel(self, report: compose.PixelReport, parts: dict) -> None:
        self.pixel_parts = (report, parts)          # the Gallery tab shows the same under an opened entry
        self.md_pixel.content = parts["verdict"]
        options = [MAP_OPTION] + [f"{self.app.stems[e.sup]} · P {v:.2f}" for e, v in zip(report.evidence,
                                                                                           report.values)]
        self.dd_large.options = options
        if self.large is not None and self.large not in [e.sup for e in report.evidence]:
            self.large = None
        if self.large is None:
            self.dd_large.value = MAP_OPTION
        else:
            self.dd_large.value = next(o for o in options if o.split(" ")[0] == self.app.stems[self.large])
        self.dd_large.disabled = False
        self.img_fusion.image = parts["chart"]
        self.md_fusion.content = parts["fusion"]
        self.md_evidence.content = parts["evidence"]
        self.img_evidence.image = parts["tiles"]
        self.img_lines.image = parts["legend"]
        self.img_fusion.visible = self.img_evidence.visible = self.img_lines.visible = True

    def _draw_sweep(self, snap, s: Settings, epoch: int, version: int) -> None:
        view = compose.sweep(snap, s, self.app.terms)
        k = len(view.maps)
        gt = self.app.gts.get(self.app.stems[s.ref])
        scores = [score(self.app.photo_set, s.ref, m, gt, s.threshold) for m in view.maps] if gt is not None else None
        img = compose.sweep_mosaic(view, self.app.stems, s.threshold,
                                   [x.at_threshold for x in scores] if scores else None)
        with self._pub:
            if not self._publishable(epoch, "sweep", version):
                return
            self.img_sweep.image = img
            self.sweep_shown = (s.ref, view, [x.at_threshold for x in scores] if scores else None, s.threshold)
            if not view.maps:
                self.md_sweep.content = "No support is ready for this reference yet."
            else:
                self.md_sweep.content = (f"P_dynamic of {self.app.stems[s.ref]} after the first 1, 2, … {k} of its "
                                         f"{k} supports, in support-set order (the paper's Fig. 5); the last one "
                                         "is the main view.")
            n = max(k, 2)
            x = np.arange(1.0, n + 1)
            if scores:
                y1 = np.array([x_.at_threshold for x_ in scores] + [np.nan] * (n - k))
                y2 = np.array([x_.best for x_ in scores] + [np.nan] * (n - k))
            else:
                y1 = y2 = np.full(n, np.nan)
            self.plot_sweep.data = (x, y1, y2)
            self.plot_sweep.scales = {"x": vu.Scale(time=False, range=(1.0, float(n))),
                                      "y": vu.Scale(range=(0.0, 1.05))}
        self._record("sweep", (self.app.stems[s.ref], k))

    def _set_best_key(self, snap, s: Settings) -> tuple:
        """What the set-wide best threshold depends on: the preset's pairs so far, the
        aggregation settings (not the reference or threshold) and the supports switched off."""
        off = tuple(sorted((i, frozenset(v)) for i, v in self.unticked.items() if v))
        return (s.preset, snap.normaliser, len(snap.pair_results),
                dataclasses.replace(s, ref=0, supports=(), threshold=0.0), off)

    def _draw_set_best(self, snap, s: Settings, epoch: int) -> None:
        if not self.app.gts:
            return
        key = self._set_best_key(snap, s)
        if key == self._set_best_key_done:
            best = self.set_best
        else:
            off = {i: set(v) for i, v in key[-1]}
            best = set_best_threshold(snap, s, self.app.gts, off)
        with self._pub:
            now = self.app.model(self.settings.preset).snapshot()
            if self._closed or now is None or key != self._set_best_key(now, self.settings):
                return                          # the settings moved on: a newer request is queued
            self._set_best_key_done, self.set_best = key, best
            for b in (self.btn_best_set, self.btn_best_set_top):
                b.label = "Use the set's best threshold" + (f" ({best.threshold:.3f})" if best else " (no map yet)")
                b.disabled = best is None
            if epoch == self._epoch:
                self._draw_notice(self.notice, self.score)
                self._draw_eval(self.settings.ref, self.dyn, self.settings.threshold, self.score)
        self._record("set best", None if best is None else best.threshold)

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

    def _ask_rerun(self) -> None:
        """Say at once that recording has started (it runs on the Rerun thread)."""
        stem = self.app.stems[self.settings.ref]
        with self._pub:
            self.md_export.content = f"Recording {stem} to Rerun… (the viewer starts on first use)"
        self.app.rerun_worker.submit(self._open_rerun_safely, self._epoch)

    def _open_rerun_safely(self, epoch: int) -> None:
        try:
            self._open_rerun(epoch)
        except Exception as e:          # shown in the tab: the viewer failed to start, a full disk, ...
            with self._pub:
                if epoch == self._epoch:
                    self.md_export.content = f"Could not record to Rerun: {type(e).__name__}: {e}"

    def _open_rerun(self, epoch: int) -> None:
        """Record the current reference (with the explained pixel, if any) into the loopback Rerun
        viewer and link to it. Only this reference's pairs are recorded (the whole set would take
        minutes on a large set while a preset is being computed)."""
        import rerun as rr

        from pipeline.rerun_log import log_run, make_blueprint
        if epoch != self._epoch:            # the reference or preset changed before this started
            return
        s = self.settings
        stem = self.app.stems[s.ref]
        snap = self.app.model(s.preset).snapshot()
        if snap is None or compose.dynamic_prob(snap, s, self.app.terms) is None:
            with self._pub:
                if epoch == self._epoch:
                    self.md_export.content = f"No map yet for {stem}: nothing to record."
            self._record("rerun skipped", stem)
            return
        p = s.params()
        sups = usable_supports(snap, s)
        supports = [[] for _ in range(self.n)]
        supports[s.ref] = sups
        results = {(s.ref, j): snap.pair_results[(s.ref, j)] for j in sups}
        res = dataclasses.replace(snap, params=p, supports=supports, pair_results=results, dynamic=[None] * self.n)
        res.dynamic[s.ref] = res.dynamic_prob(s.ref, sups)
        web = self.app.rerun_viewer()
        rec = rr.RecordingStream("crowdcam", recording_id=f"{self.app.photo_set.name}-{stem}-{int(time.time())}")
        rec.connect_grpc(web.grpc_uri)
        desc = log_run(res, rec, focus=s.ref, pixels=None if self.pixel is None else self.pixel[None], gts=self.app.gts,
                       threshold=s.threshold)
        rec.send_blueprint(make_blueprint(desc))
        rec.flush()
        self.app.keep_recording(rec)
        with self._pub:
            if epoch != self._epoch:
                return
            self.md_export.content = (f"Recorded {stem}: [open the Rerun viewer]({web.url}) (served on this "
                                      "machine's loopback only; the viewer takes a few seconds to load).")
        self._record("rerun", web.url)


def rejected_markdown(reasons: dict[str, list[str]], order: list[str] | None = None,
                      per_photo_up_to: int = 12) -> str:
    """The photos rejected by the geometry test, by reason (reason -> stems): one line per photo
    when there are few, else one line per kind of reason (its words before the figures) with
    its photos, in the order of `order` (the set's stems)."""
    n = sum(len(v) for v in reasons.values())
    if not n:
        return ""
    if n <= per_photo_up_to:
        lines = [f"- **{stem}**: {why}" for why, stems in reasons.items() for stem in stems]
        return "\n\nRejected by the geometry test:\n" + "\n".join(lines)
    kinds: dict[str, list[str]] = {}
    for why, stems in reasons.items():
        kinds.setdefault(why.split(" (")[0].split(":")[0], []).extend(stems)
    rank = {stem: k for k, stem in enumerate(order or [])}
    lines = [f"- {kind} ({len(stems)}): {', '.join(sorted(stems, key=lambda x: (rank.get(x, 0), x)))}"
             for kind, stems in sorted(kinds.items(), key=lambda kv: -len(kv[1]))]
    return f"\n\nRejected by the geometry test ({n} photos, by kind of reason):\n" + "\n".join(lines)


def _noev_label(mode: str) -> str:
    return next(k for k, v in NO_EVIDENCE.items() if v == mode)


def _remap_range(value) -> tuple[float, float]:
    """The two number boxes of the remap range as a valid (lo, hi): ordered, in [0, 1], at least
    0.02 apart."""
    lo, hi = sorted(float(np.clip(v, 0.0, 1.0)) for v in value)
    if hi - lo < 0.02:
        lo, hi = (lo, lo + 0.02) if lo <= 0.98 else (0.98, 1.0)
    return (lo, hi)


def _quat_to_matrix(wxyz: np.ndarray) -> np.ndarray:
    w, x, y, z = wxyz / np.linalg.norm(wxyz)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
