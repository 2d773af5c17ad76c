"""Presets side by side (issue 12, item 5): a "Presets" tab with the shown reference's map under
`paper`, `default` and `peer-homography`, as three panels that stay in step.

Each panel is the preset's own map (its pipeline settings: `SetResult.dynamic_prob` over the
reference's finished supports of that preset's run, the function detect uses) at the preset's own
threshold, with its Jaccard there and at its best threshold when there is ground truth. The
clicked pixel is marked in all three, and "Zoom on the clicked point" crops all three to the same
window around it. A preset the inspector has not run yet says so and offers a button that starts
its run in the background (Inspector.model: the same run the Preset dropdown starts); a run in
progress says how many of the reference's pairs are in.

Maps are cached per (preset, reference, pairs in); a pixel or zoom change only redraws the marks.
Drawn on a redrawer of its own: the main view never waits for it.
"""

from __future__ import annotations

import threading
import time

import cv2
import numpy as np

from pipeline.output import heat_overlay

from . import render
from .model import preset_params, score

PRESETS_SHOWN = ("paper", "default", "peer-homography")
PANEL_WIDTH = 312                 # as the other pictures of the left panel
ZOOM_SHARE = 0.4                  # the zoomed window: this share of the photo's longer side
C_GT = (40, 200, 60)
HELP = ("The reference's map under each preset, at the preset's own threshold (red outline: its mask; green: "
        "ground truth), with its Jaccard there and at its best threshold. The clicked point is marked in all "
        "three. paper: the paper's method; default: ours; peer-homography: a 2-D baseline (each photo aligned "
        "by one homography, colours compared).")


def _cross(img: np.ndarray, xy, size: int) -> None:
    p = (int(round(xy[0])), int(round(xy[1])))
    cv2.drawMarker(img, p, (0, 0, 0), cv2.MARKER_CROSS, size, 5)
    cv2.drawMarker(img, p, (255, 255, 255), cv2.MARKER_CROSS, size, 2)


def zoom_window(size: tuple[int, int], xy, share: float = ZOOM_SHARE) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1): a square window of `share` of the photo's longer side, centred on xy and
    kept inside the photo of size (h, w)."""
    h, w = size
    side = max(8, int(round(share * max(h, w))))
    sw, sh = min(side, w), min(side, h)
    x0 = int(np.clip(round(xy[0] - sw / 2), 0, w - sw))
    y0 = int(np.clip(round(xy[1] - sh / 2), 0, h - sh))
    return x0, y0, x0 + sw, y0 + sh


def panel_picture(base: np.ndarray, pixel, window, width: int = PANEL_WIDTH) -> np.ndarray:
    """The preset's overlay (h, w, 3) uint8 cropped to `window` (x0, y0, x1, y1) or whole, scaled
    to `width`, the pixel (x, y) marked; (h', width, 3) uint8 RGB."""
    x0, y0, x1, y1 = window if window is not None else (0, 0, base.shape[1], base.shape[0])
    crop = base[y0:y1, x0:x1]
    f = width / crop.shape[1]
    out = cv2.resize(crop, (width, max(1, round(crop.shape[0] * f))),
                     interpolation=cv2.INTER_NEAREST if f > 1 else cv2.INTER_AREA)
    if pixel is not None:
        u, v = (pixel[0] - x0 + 0.5) * f - 0.5, (pixel[1] - y0 + 0.5) * f - 0.5
        if 0 <= u < out.shape[1] and 0 <= v < out.shape[0]:
            _cross(out, (u, v), 18)
    return out


class PresetPanels:
    """The Presets tab of one session. shown[preset]: (reference, pixel or None, window or None,
    state) last published in that panel, state "map" / "not run" / "computing" / "none";
    maps: (preset, reference, pairs in) -> (overlay, Score or None, threshold)."""

    def __init__(self, session):
        from .app import Redrawer          # app imports this module: at call time, not at import
        self.s = session
        self.shown: dict[str, tuple] = {}
        self.maps: dict[tuple, tuple] = {}
        self.draw_ms: list[float] = []
        self._listening: set[str] = set()
        self._lock = threading.Lock()
        gui = session.client.gui
        self.panels = {}
        with session.panel.add_tab("Presets"):
            self.md_head = gui.add_markdown("")
            self.cb_zoom = gui.add_checkbox("Zoom on the clicked point", initial_value=False,
                                            hint="all three panels show the same window around the clicked point")
            for p in PRESETS_SHOWN:
                md = gui.add_markdown(f"**{p}**: …")
                img = gui.add_image(render.message("…"), format="jpeg", jpeg_quality=85)
                btn = gui.add_button(f"Compute {p}", visible=False,
                                     hint=f"run the {p} preset on this set in the background (as choosing it "
                                          "in Preset would); the pairs are cached")
                btn.on_click(lambda _ev, p=p: self.compute(p))
                self.panels[p] = (md, img, btn)
            with gui.add_folder("About the panels", expand_by_default=False):
                gui.add_markdown(HELP)
        self.cb_zoom.on_update(lambda _ev: self.draw.request("marks"))
        self.draw = Redrawer(f"tab{session.client.client_id}-presets", self._draw)
        for p in PRESETS_SHOWN:
            if p in session.app.models:
                self._listen(p)
        self.draw.request("maps")

    # ------------------------------------------------------------------ events
    def on_event(self, what: str, value) -> None:
        if what in ("ref", "preset", "sweep"):
            self.draw.request("maps")
        elif what == "pixel":
            self.draw.request("marks")

    def _listen(self, preset: str) -> None:
        with self._lock:
            if preset in self._listening:
                return
            self._listening.add(preset)
        self.s.app.model(preset).add_listener(self._model_changed)

    def _model_changed(self, _model) -> None:
        if not self.s._closed:
            self.draw.request("maps")

    def compute(self, preset: str) -> None:
        """Start the preset's run (Inspector.model), as the Preset dropdown would; one run at a time
        (two runs of different presets at once in one process broke the second: KeyError 'hog_map')."""
        if self._busy():
            return
        self._listen(preset)
        self.s._record("presets compute", preset)
        self.draw.request("maps")

    def _busy(self) -> str | None:
        """The preset whose run is going on, if any."""
        return next((p for p, m in list(self.s.app.models.items()) if m.status in ("waiting", "running")), None)

    def close(self) -> None:
        self.draw.stop()
        for p in list(self._listening):
            m = self.s.app.models.get(p)
            if m is not None and self._model_changed in m._listeners:
                m._listeners.remove(self._model_changed)

    # ------------------------------------------------------------------ drawing (own thread)
    def _map(self, preset: str, ref: int):
        """(state, text, entry): the preset's map of ref, from cache or computed now."""
        app = self.s.app
        if preset not in app.models:
            return "not run", f"**{preset}**: not computed yet for this set.", None
        model = app.models[preset]
        snap = model.snapshot()
        if model.status == "failed":
            return "none", f"**{preset}**: the run failed ({model.error}).", None
        if snap is None:
            return "computing", f"**{preset}**: computing… (the geometry)", None
        sups = list(snap.supports[ref])
        done = [j for j in sups if (ref, j) in snap.pair_results]
        if not sups:
            return "none", f"**{preset}**: {app.stems[ref]} has no supports under this preset.", None
        if len(done) < len(sups) and model.status in ("waiting", "running"):
            return "computing", f"**{preset}**: computing… ({len(done)} of {len(sups)} pairs in)", None
        if not done:
            return "none", f"**{preset}**: none of the pairs was computed.", None
        key = (preset, ref, len(done))
        entry = self.maps.get(key)
        if entry is None:
            photo = app.photo_set.photos[ref]
            dyn = snap.dynamic_prob(ref, done)
            t = float(preset_params(preset, app.max_side, app.changes).aggregate.threshold)
            base = heat_overlay(photo.rgb, dyn, dyn > t, 0.55)
            gtw = app.gts_working.get(app.stems[ref])
            if gtw is not None:
                contours, _ = cv2.findContours(gtw.astype(np.uint8), cv2.RETR_EXTERNAL,
                                               cv2.CHAIN_APPROX_SIMPLE)
                cv2.drawContours(base, contours, -1, C_GT, max(1, round(max(base.shape[:2]) / 400)), cv2.LINE_AA)
            gt = app.gts.get(app.stems[ref])
            sc = score(app.photo_set, ref, dyn, gt, t) if gt is not None else None
            entry = (base, sc, t, len(done))
            self.maps = {k: v for k, v in self.maps.items() if k[1] == ref}     # this reference's only
            self.maps[key] = entry
        base, sc, t, n = entry
        text = f"**{preset}**: threshold {t:.2f}, {n} supports"
        if sc is not None:
            text += f"; **Jaccard {sc.at_threshold:.3f}** (best {sc.best:.3f} at {sc.best_threshold:.2f})"
        return "map", text + ".", entry

    def _draw(self, _what: set[str]) -> None:
        s = self.s
        t0 = time.perf_counter()
        ref = s.settings.ref
        pixel = None if s.pixel is None else (float(s.pixel[0]), float(s.pixel[1]))
        size = s.app.photo_set.photos[ref].size
        window = zoom_window(size, pixel) if (self.cb_zoom.value and pixel is not None) else None
        out = {}
        for p in PRESETS_SHOWN:
            state, text, entry = self._map(p, ref)
            pic = panel_picture(entry[0], pixel, window) if entry is not None else None
            out[p] = (state, text, pic)
        busy = self._busy()
        head = (f"**{s.app.stems[ref]}** under three presets" +
                (f"; point ({pixel[0]:.0f}, {pixel[1]:.0f}) marked in all three" if pixel is not None
                 else "; click a point of the photo to mark it in all three") + ".")
        with s._pub:
            if s.settings.ref != ref or s._closed:
                return                                           # a newer draw follows
            self.md_head.content = head
            for p, (state, text, pic) in out.items():
                md, img, btn = self.panels[p]
                md.content = text
                img.image = pic if pic is not None else render.message(
                    "not computed yet" if state == "not run" else "computing…" if state == "computing" else "—")
                btn.visible = state == "not run"
                btn.disabled = busy is not None
                btn.label = f"Compute {p}" if busy is None else f"Compute {p} (after the {busy} run)"
                self.shown[p] = (ref, pixel if pic is not None else None, window, state)
        self.draw_ms = (self.draw_ms + [1000 * (time.perf_counter() - t0)])[-50:]
        s._record("presets shown", (s.app.stems[ref], pixel, tuple(out[p][0] for p in PRESETS_SHOWN)))
