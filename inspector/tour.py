"""The guided tour, presenter mode and prepared links of one browser tab (issue 12, items 1-3).

A `Tour` belongs to an app.Session and drives it through the session's own controls and
redrawers: the tour never computes a map. Its step pictures replace the main view's picture
(Session._draw_fast calls `picture`, then `shown`), so a step is drawn by the same thread, from
the same snapshot, as the plain view, and every change the user makes (a click, another
support, the threshold) redraws the step. The words and pictures are in tour_views.

The tour panel (docked left) holds the step's title and words, previous / next, the steps by
number, the support shown in steps 2-5 and presenter mode. Arrow keys: a listener on `window`
(capture phase, before viser's camera and React see the key) turns the page while the tour is
on and no control has the focus (the body, the 3-D canvas or the tour's own previous / next
button): it clicks Previous / Next, and up / down do nothing; either way the key never reaches
the camera. A focused control keeps its key (app.KEYS_STAY_WITH_CONTROLS keeps it from the
camera).

Step 1 shows the photos where they were taken: when the preset has the set's cameras (the
`default` preset's reconstruction, SetResult.cameras), the tour switches the main view to the
session's Geometry (3-D) view (geometry_view.py; drawn by its own redrawer, which tells the tour
when the step is on screen) and back to the photo view for steps 2-7; without cameras (`paper`,
`peer-homography`) step 1 is the grid of photos, each captioned with what it is to the reference.
Leaving the tour puts back the view the tab had before.

Prepared links: viser does not tell the server the page's URL (its websocket request carries no
query), so the same page script hands `location.search` to the server through a text field of
the "Prepared link" folder (state.py has the format); "Link to this view" writes the link of the
current state.
"""

from __future__ import annotations

import html
import threading
import time

import numpy as np

from . import render
from . import tour_views as tv
from .model import score, usable_supports
from .state import N_STEPS, PreparedState, from_query, to_query

PREV, NEXT = "◀ Previous", "Next ▶"
START = "Take the guided tour"
LINK_LABEL = "Open a link"
MARKER_ID = "crowdcam-tour-on"
TOUR_WIDTH = {False: 480, True: 600}
TEXT_SCALE = {False: 1.0, True: 1.3}     # the type in the step pictures (presenter mode: larger)
SOURCE_WORDS = {"reconstruction": "the set's reconstruction (all the cameras placed together; ours)",
                "two-view": "this pair's own matches (as in the paper)",
                "homography": "one homography (a shot from about the same spot, or a flat scene; ours)"}
PRESENTER_CSS = """<style>
:root { font-size: 125% !important; }
.mantine-Paper-root p, .mantine-Paper-root li, .mantine-Paper-root td { font-size: 1.05rem !important;
  line-height: 1.45 !important; }
</style>"""

_JS = """if(!window.__crowdcamTour){window.__crowdcamTour=1;
var PREV=%(prev)s,NEXT=%(next)s;
function btn(t){var b=document.querySelectorAll('button');for(var i=0;i<b.length;i++){if(b[i].textContent.trim()===t)return b[i];}return null;}
window.addEventListener('keydown',function(e){
 if(!document.getElementById(%(marker)s))return;
 var k=e.key;if(k!=='ArrowLeft'&&k!=='ArrowRight'&&k!=='ArrowUp'&&k!=='ArrowDown')return;
 var a=document.activeElement,tx=a&&a.tagName==='BUTTON'?a.textContent.trim():'';
 if(!(!a||a===document.body||a.tagName==='CANVAS'||tx===PREV||tx===NEXT))return;
 e.preventDefault();e.stopImmediatePropagation();
 if(e.repeat)return;
 var b=k==='ArrowRight'?btn(NEXT):(k==='ArrowLeft'?btn(PREV):null);if(b)b.click();},true);
var q=location.search;
function field(){var l=document.querySelectorAll('label');for(var i=0;i<l.length;i++){
 if(l[i].textContent.trim()!==%(field)s)continue;var c=document.getElementById(l[i].htmlFor);
 if(c&&c.tagName==='INPUT')return c;if(c&&c.querySelector('input'))return c.querySelector('input');
 for(var p=l[i].parentElement,k=0;p&&k<4;p=p.parentElement,k++){var x=p.querySelector('input');if(x)return x;}}return null;}
if(q&&q.length>1){var n=0;var iv=setInterval(function(){var el=field();
 if(el){clearInterval(iv);var set=Object.getOwnPropertyDescriptor(HTMLInputElement.prototype,'value').set;
 set.call(el,q);el.dispatchEvent(new Event('input',{bubbles:true}));}
 else if(++n>400){clearInterval(iv);}},50);}}"""


def page_script() -> str:
    """The page script (keys and the prepared link), installed by an image that fails to load:
    viser runs no <script> from HTML. The link's field is found by its label (a text field's
    DOM id is Mantine's own, not the handle's)."""
    js = _JS % {"prev": repr(PREV), "next": repr(NEXT), "marker": repr(MARKER_ID), "field": repr(LINK_LABEL)}
    return f'<img src="data:," alt="" style="display:none" onerror="{html.escape(js, quote=True)}">'


class Tour:
    """The tour of one tab. step: 0 (off) or 1..7; sup: the support steps 2-5 show (None: the
    first epipolar support); step_ms: server-side time from a step change to its picture sent."""

    def __init__(self, session):
        self.s = session
        self.step = 0
        self.sup: int | None = None
        self.presenter = False
        self.layout: tv.Picture | None = None
        self.step_ms: list[float] = []
        self._t_step: float | None = None
        self._auto_pixel_ref: int | None = None        # the reference a default point was chosen for
        self.in_3d = False                              # step 1 is shown in the Geometry (3-D) view
        self._look_used: tv.Look | None = None          # how the last step picture was laid out
        self._view_chosen: tuple | None = None          # (step, cameras known) the main view was chosen for
        self._view_before: str | None = None            # the tab's main view before the tour
        self._sup_options: list[str] = []
        self._lock = threading.Lock()
        self.panel = None
        gui = session.client.gui
        self.btn_start = gui.add_button(START, order=-10, hint="Seven steps through the method on this set, "
                                                               "each live; arrow keys turn the pages.")
        self.btn_start.on_click(lambda _ev: self.start(self.step or 1))
        with gui.add_folder("Prepared link"):      # open: a folded folder has no field in the page
            self.txt_link = gui.add_text(LINK_LABEL, "", hint="paste a prepared link (or its ?query) to open "
                                                                 "its state; a link opened in the browser is "
                                                                 "read from here")
            self.btn_link = gui.add_button("Link to this view", hint="a link that opens this set, reference, "
                                                                     "supports, threshold, point and tour step")
            self.md_link = gui.add_markdown("")
        gui.add_html(page_script())
        self.txt_link.on_update(lambda _ev: self._on_link_text())
        self.btn_link.on_click(lambda _ev: self.show_link())

    # ------------------------------------------------------------------ the panel
    def _build_panel(self) -> None:
        gui = self.s.client.gui
        self.panel = gui.add_panel()
        with self.panel.add_tab("Tour"):
            self.html_marker = gui.add_html(f'<span id="{MARKER_ID}"></span>')
            self.md_title = gui.add_markdown("")
            self.md_text = gui.add_markdown("")
            self.bg_nav = gui.add_button_group("Page", [PREV, NEXT], hint="or the arrow keys ← → (when no "
                                                                          "control has the focus)")
            self.bg_step = gui.add_button_group("Step", [str(k) for k in range(1, N_STEPS + 1)],
                                                hint="go to a step directly")
            self.md_live = gui.add_markdown("")
            self.btn_best = gui.add_button("Use this photo's best threshold", visible=False,
                                           hint="the threshold with the highest Jaccard for this photo (§4.2): "
                                                "the mask and the score follow")
            self.img_side = gui.add_image(tv.busy_picture("").rgb, format="png", visible=False)
            self.dd_sup = gui.add_dropdown("Support shown", options=["…"], initial_value="…",
                                           hint="the support whose pair steps 2 to 5 show")
            self.cb_presenter = gui.add_checkbox("Presenter mode", initial_value=self.presenter,
                                                 hint="large type, the picture on the whole screen, the "
                                                      "controls folded away (open them from their rails)")
            self.btn_stop = gui.add_button("Leave the tour")
        self.bg_nav.on_click(lambda ev: self.go(self.step + (1 if ev.target.value == NEXT else -1)))
        self.bg_step.on_click(lambda ev: self.go(int(ev.target.value)))
        self.dd_sup.on_update(lambda _ev: self._on_sup())
        self.cb_presenter.on_update(lambda _ev: self.set_presenter(bool(self.cb_presenter.value)))
        self.btn_stop.on_click(lambda _ev: self.stop())
        self.btn_best.on_click(lambda _ev: self.s._use_best("photo"))
        self.panel.dock_left()
        self.panel.set_width(TOUR_WIDTH[self.presenter])

    def start(self, step: int = 1) -> None:
        if self.panel is None:
            self._view_before = self.s.view
            self._build_panel()
            self.s.panel.minimize()
            self.btn_start.visible = False
        self.set_presenter(self.presenter)
        self.go(step)

    def stop(self) -> None:
        if self.panel is None:
            return
        with self._lock:
            self.step = 0
            self.layout = None
            self.in_3d = False
        self.panel.remove()
        self.panel = None
        self.s.set_view(self._view_before or "photo")
        self.s.panel.expand()
        self.s.client.gui.main_panel.expand()
        self.btn_start.visible = True
        self.s.fast.request("main")
        self.s._record("tour", 0)

    def set_presenter(self, on: bool) -> None:
        self.presenter = on
        if self.panel is None:
            return
        self.html_marker.content = f'<span id="{MARKER_ID}"></span>' + (PRESENTER_CSS if on else "")
        self.panel.set_width(TOUR_WIDTH[on])
        if on:
            self.s.client.gui.main_panel.minimize()
        else:
            self.s.client.gui.main_panel.expand()
        if self.cb_presenter.value != on:
            self.cb_presenter.value = on
        if self.step:
            self.s.fast.request("main")          # the pictures' type follows
        self.s._record("presenter", on)

    def go(self, step: int) -> None:
        step = int(np.clip(step, 1, N_STEPS))
        if self.panel is None:
            self.start(step)
            return
        with self._lock:
            self.step = step
            self._t_step = time.perf_counter()
            self.in_3d = False
            self._view_chosen = None
        st = tv.STEPS[step - 1]
        self.md_title.content = f"### Step {step} of {N_STEPS}: {st.title}"
        self.md_text.content = st.text
        self.bg_nav.disabled = False
        self.dd_sup.visible = 2 <= step <= 5
        self.md_live.content = "*computing…*"
        self.img_side.visible = False
        self.btn_best.visible = False
        self.s.fast.request("main")
        self.s._record("tour", step)

    def panel_width(self) -> int:
        return TOUR_WIDTH[self.presenter]

    def look(self) -> tv.Look:
        """How the step's picture will be seen: the canvas's shape as the browser last reported
        it (the step's panels go side by side or one above the other to fill it) and the type's
        size (larger in presenter mode)."""
        try:
            aspect = float(self.s.client.camera.aspect)
        except Exception:                   # no camera report from the browser yet
            aspect = None
        return tv.Look(aspect if aspect and np.isfinite(aspect) and aspect > 0 else None, TEXT_SCALE[self.presenter])

    def on_canvas(self, aspect: float) -> None:
        """The browser reported its canvas (a resize, presenter mode's panels): redraw the step
        when its picture was laid out for another shape."""
        used = self._look_used
        if self.step and self.layout is not None and used is not None and \
                (used.aspect is None or abs(aspect - used.aspect) > 0.03 * used.aspect):
            self.s.fast.request("main")

    def _on_sup(self) -> None:
        v = self.dd_sup.value
        if v in self.s.app.stems:
            j = self.s.app.stems.index(v)
            if j != self.sup:
                self.sup = j
                self.s.fast.request("main")
                self.s._record("tour support", v)

    # ------------------------------------------------------------------ hooks from the session
    def on_event(self, what: str, value) -> None:
        """The session recorded an event: redraw the step when what it shows changed."""
        if self.step == 0:
            return
        if what in ("explained", "sweep") or (what == "set best" and self.step == 7):
            self.s.fast.request("main")

    def on_click(self, ev) -> bool:
        """A click on the main view while the tour is on: a reference pixel when the step's
        picture holds the reference (True: the tour handled it)."""
        layout = self.layout
        if self.step == 0 or layout is None:
            return False
        o, d = np.asarray(ev.ray_origin, np.float64), np.asarray(ev.ray_direction, np.float64)
        if abs(d[2]) < 1e-12:
            return True
        p = o + d * (-o[2] / d[2])                    # the picture lies in its local z = 0 plane, centred
        H, W = layout.rgb.shape[:2]
        rw = float(self.s.scene_img.render_width)
        cx, cy = (p[0] / rw + 0.5) * W - 0.5, (p[1] + 0.5) * H - 0.5
        xy = layout.to_reference(cx, cy, self.s.app.photo_set.photos[self.s.settings.ref].size)
        if xy is not None:
            self.pick(xy)
        return True

    def picture_to_canvas(self, cx: float, cy: float) -> tuple[float, float]:
        """Where pixel (cx, cy) of the step's picture appears in the canvas, as fractions of its
        width and height, from the camera the browser last reported (tests and screenshots).
        Fractions, not pixels: viser reports its render size, which it scales below the canvas's
        on-screen size on large windows and under load."""
        from .app import _quat_to_matrix
        H, W = self.layout.rgb.shape[:2]
        rw = float(self.s.scene_img.render_width)
        X = np.array([((cx + 0.5) / W - 0.5) * rw, (cy + 0.5) / H - 0.5, 0.0])
        cam = self.s.client.camera
        R = _quat_to_matrix(np.asarray(cam.wxyz, np.float64))
        x = R.T @ (X - np.asarray(cam.position, np.float64))
        f = 0.5 * cam.image_height / np.tan(cam.fov / 2)
        return (0.5 + f * x[0] / x[2] / cam.image_width), (0.5 + f * x[1] / x[2] / cam.image_height)

    def pick(self, xy) -> None:
        """Explain reference pixel xy (what a click on the plain view does)."""
        s = self.s
        s.pixel = np.asarray(xy, np.float64)
        with s._pub:
            s._bump("pixel")
            s.md_pixel.content = f"**Pixel ({s.pixel[0]:.0f}, {s.pixel[1]:.0f})**: …"
        s.fast.request("main")
        s.slow.request("pixel")
        s._record("pixel", (round(float(s.pixel[0]), 1), round(float(s.pixel[1]), 1)))

    def shown(self) -> None:
        """The step's picture has been sent (called by the session right after)."""
        with self._lock:
            if self._t_step is not None and self.layout is not None and not self.in_3d:
                self.step_ms.append(1000 * (time.perf_counter() - self._t_step))
                self._t_step = None
                self.s._record("tour shown", self.step)

    def shown_3d(self) -> None:
        """The Geometry view has been drawn (called by the session's geometry redrawer): step 1's
        cameras, with their pictures, are sent."""
        with self._lock:
            if self._t_step is not None and self.in_3d and self.step == 1 and self.s.view == "geometry" and \
                    self.s.geo is not None and self.s.geo.ref == self.s.settings.ref:
                self.step_ms.append(1000 * (time.perf_counter() - self._t_step))
                self._t_step = None
                self.s._record("tour shown", self.step)

    def _choose_view(self, snap) -> None:
        """The main view of the step: step 1 in the Geometry (3-D) view when the preset has
        cameras, the photo view otherwise (while step 1 waits for the geometry, and for steps
        2-7). Chosen when a step is entered and again when whether there are cameras changes
        (another preset); in between the user's own choice of view stands."""
        state = (self.step, (tv.has_cameras(snap) if snap is not None else None) if self.step == 1 else None)
        if self._view_chosen == state:
            return
        self._view_chosen = state
        self.s.set_view("geometry" if state[1] else "photo")

    # ------------------------------------------------------------------ the step's picture
    def _support(self, snap, sups: list[int]) -> int | None:
        if self.sup in sups:
            return self.sup
        ref = self.s.settings.ref
        epi = [j for j in sups if snap.kind(ref, j) == "epipolar"]      # without loading the pairs
        return (epi or sups or [None])[0]

    def picture(self, snap, img: np.ndarray, dyn: np.ndarray | None) -> np.ndarray:
        """The main view's picture for the current step (img: the plain view's picture, dyn its
        map); the plain picture when the tour is off. Also updates the panel's live words."""
        step = self.step
        if step == 0 or self.panel is None:
            self.layout = None
            return img
        s = self.s
        app, st = s.app, s.settings
        ref, stems = st.ref, app.stems
        photos = app.photo_set.photos
        sups = usable_supports(snap, st) if snap is not None else []
        sup = self._support(snap, sups) if sups else None
        self._sync_sup_options(sups, sup)
        if step >= 2 and s.pixel is None and dyn is not None and self._auto_pixel_ref != ref:
            self._auto_pixel_ref = ref
            self.pick(tv.default_pixel(dyn, app.gts_working.get(stems[ref])))
        pixel, report = s.pixel, s.report
        if report is not None and (report.ref != ref or pixel is None or not np.array_equal(report.xy, pixel)):
            report = None
        ev = next((e for e in report.evidence if e.sup == sup), None) if report is not None and sup is not None \
            else None
        val = report.values[[e.sup for e in report.evidence].index(sup)] if ev is not None else None
        live, side = "", None
        look = self.look()
        self._choose_view(snap)
        if step == 1 and s.view == "geometry" and tv.has_cameras(snap):
            model = app.model(st.preset)
            rel = [self._relation(model, snap, ref, j) for j in range(len(stems))]
            live = tv.cameras_words(stems, ref, rel, snap.cameras)
            with self._lock:
                self.in_3d, self.layout = True, None
                pending = self._t_step is not None
            if pending:
                s.geo_draw.request("scene", "ray")      # it tells the tour when the cameras are on screen
            self.md_live.content = live
            self.img_side.image = render.stack([tv.photos_strip(photos, stems, ref, rel, self.panel_width()),
                                                tv.cameras_key(self.panel_width())], gap=10)
            self.img_side.visible = True
            return img                              # the photo view is hidden meanwhile
        if step == 1:
            model = app.model(st.preset)
            rel = [self._relation(model, snap, ref, j) for j in range(len(stems))]
            pic = tv.photos_picture(photos, stems, ref, rel, look=look)
            n_sup = len(snap.supports[ref]) if snap is not None else 0
            live = (f"Reference **{stems[ref]}** (change it in the controls on the right): {n_sup} supports of "
                    f"{len(stems) - 1} other photos. " + tv.no_cameras_words(snap, st.preset))
        elif snap is None or sup is None:
            pic = tv.busy_picture("No support is ready for this reference yet: its pairs are being computed.",
                                  look=look)
        elif step == 2:
            g = snap.pairs[(ref, sup)]
            pic = tv.pair_picture(photos[ref].rgb, photos[sup].rgb, g, pixel, stems[ref], stems[sup], look)
            source = SOURCE_WORDS.get(g.source, g.source)
            live = (f"Pair **{stems[ref]} → {stems[sup]}**: {len(g.inliers_ref)} matched features; its geometry "
                    f"comes from {source}" + (f", lines sure to ±{g.uncertainty_px:.1f} px"
                                              if np.isfinite(g.uncertainty_px) else "") + ".")
        elif step == 3:
            pair = snap.pair_results[(ref, sup)]
            pic = tv.strips_picture(photos[ref].rgb, photos[sup].rgb, pair, pixel, ev, stems[ref], stems[sup], look)
            if pair.kind == "epipolar" and pair.strips is not None:
                strips = pair.strips
                covered = strips.n_fans * (strips.L // strips.stride)   # fans x patches along a strip (9 in paper)
                fans = (f"{strips.n_fans} fans (each shifted by 1/{strips.n_fans} of a strip" if strips.n_fans > 1 else
                        "1 fan (a pair that is also depth-swept searches one fan in default")
                live = (f"{strips.n_strips} strips in {fans}: every pixel is covered {covered} times); patches "
                        f"{strips.L} px long.")
        elif step == 4:
            if ev is None:
                pic = tv.busy_picture("Finding the candidates of the clicked point…" if pixel is not None
                                      else "Click a point (steps 2, 3, 5, 6 or 7) to see its candidates.", look=look)
            else:
                pic = tv.candidates_picture(snap, report, ev, stems[sup], look=look)
                if ev.patch is not None and len(ev.patch.cand_quads):
                    p = ev.patch
                    live = (f"{len(p.cand_quads)} candidates; best HOG similarity "
                            f"**{p.sim_hog[p.best_hog]:.2f}**, best colour **{p.sim_color[p.best_color]:.2f}**.")
        elif step == 5:
            mp = app.terms.match_prob(snap, ref, sup, st.params())
            pic = tv.support_map_picture(photos[ref].rgb, photos[sup].rgb, mp, pixel, val, stems[ref], stems[sup],
                                         look=look)
            if val is not None:
                says = "a match: says static" if val > 0.5 else ("no opinion" if val == 0.5 else
                                                                 "no match: says moving")
                live = f"At the point, **{stems[sup]}** gives P(x|I_s) = **{val:.2f}** ({says})."
        elif step == 6:
            sw = s.sweep_shown
            sweep = (sw[1], sw[2]) if sw is not None and sw[0] == ref else None
            pic = tv.fusion_picture(img, sweep, stems[ref], len(sups), stems, dyn, st.threshold,
                                    (s.layers.mask, bool(app.gts) and s.layers.gt), look=look)
            if report is not None:
                live = s.md_pixel.content
                side = s.img_fusion.image if s.img_fusion.visible else None
        else:
            gt = app.gts_working.get(stems[ref])
            sc = s.score if gt is not None else None
            if gt is not None and sc is None and dyn is not None:
                sc = score(app.photo_set, ref, dyn, app.gts.get(stems[ref]), st.threshold)
            pic = tv.result_picture(photos[ref].rgb, dyn, gt, st.threshold, pixel, sc, stems[ref], look=look)
            live = s.md_eval.content if gt is not None else "This photo has no ground truth."
            offer = sc is not None and abs(sc.best_threshold - st.threshold) > 0.005
            if offer:
                self.btn_best.label = f"Use this photo's best threshold ({sc.best_threshold:.3f})"
            self.btn_best.visible = offer
        with self._lock:
            self.layout, self.in_3d, self._look_used = pic, False, look
        if step >= 2 and pixel is not None and step not in (6,):
            live = f"Point ({pixel[0]:.0f}, {pixel[1]:.0f}). " + live
        self.md_live.content = live
        if side is not None:
            self.img_side.image = side
        self.img_side.visible = side is not None
        return pic.rgb

    def _relation(self, model, snap, ref: int, j: int) -> str:
        if j == ref:
            return "reference"
        state, why = model.pair_state(ref, j)
        if state == "rejected":
            return f"rejected: {why}"
        if state == "unused":
            return "not used: enough better supports"
        g = snap.pairs.get((ref, j)) if snap is not None else None
        kind = "homography" if g is not None and g.H is not None else "epipolar"
        src = f" ({g.source})" if g is not None and g.source else ""
        return f"support · {kind}{src}" + (" · computing…" if state == "computing" else "")

    def _sync_sup_options(self, sups: list[int], sup: int | None) -> None:
        opts = [self.s.app.stems[j] for j in sups] or ["…"]
        if opts != self._sup_options:
            self._sup_options = opts
            self.dd_sup.options = opts
        value = self.s.app.stems[sup] if sup is not None else "…"
        if self.dd_sup.value != value:
            self.sup = sup
            self.dd_sup.value = value

    # ------------------------------------------------------------------ prepared links
    def current_state(self) -> PreparedState:
        s = self.s
        st, stems = s.settings, s.app.stems
        off = tuple(stems[j] for j in sorted(s.unticked.get(st.ref, set())))
        return PreparedState(set=s.app.photo_set.name, preset=st.preset, ref=stems[st.ref], off=off,
                             threshold=round(st.threshold, 3),
                             pixel=None if s.pixel is None else (float(s.pixel[0]), float(s.pixel[1])),
                             step=self.step or None, support=stems[self.sup] if self.step and self.sup is not None
                             else None, presenter=True if self.presenter and self.step else None)

    def link(self) -> str:
        return self.s.app.url + "?" + to_query(self.current_state())

    def show_link(self) -> None:
        url = self.link()
        self.md_link.content = f"[{url}]({url})\n\n```\n{url}\n```"
        self.s._record("link", url)

    def _on_link_text(self) -> None:
        text = self.txt_link.value.strip()
        if not text or text == "?":
            return
        try:
            st = from_query(text)
        except ValueError as e:
            self.md_link.content = f"**Cannot open this link**: {e}."
            return
        self.apply(st)

    def apply(self, st: PreparedState) -> None:
        """Open a prepared state: each key through the control that a user would use."""
        s, app = self.s, self.s.app
        stems = app.stems
        problems = []
        if st.set is not None and st.set != app.photo_set.name:
            problems.append(f"the link is for the set `{st.set}`, this is `{app.photo_set.name}`")
        if st.preset is not None and st.preset != s.settings.preset:
            if st.preset in s.dd_preset.options:
                s.dd_preset.value = st.preset
            else:
                problems.append(f"no preset `{st.preset}`")
        if st.ref is not None:
            if st.ref in stems:
                s.ref_chosen = True
                if stems[s.settings.ref] != st.ref:
                    s.dd_ref.value = st.ref            # fires _on_ref
            else:
                problems.append(f"no photo `{st.ref}`")
        ref = s.settings.ref
        if st.off is not None:
            bad = [x for x in st.off if x not in stems]
            problems += [f"no photo `{x}`" for x in bad]
            for j, stem in enumerate(stems):
                if j == ref:
                    continue
                want_on = stem not in st.off
                box = s._boxes.get(j) if s._box_ref == ref else None
                if box is not None and not box.disabled:
                    if bool(box.value) != want_on:
                        box.value = want_on            # fires _on_support
                else:
                    off = s.unticked.setdefault(ref, set())
                    (off.discard if want_on else off.add)(j)
            s._on_control()
        if st.threshold is not None:
            s.sl_thr.value = float(st.threshold)       # fires _on_control
        if st.pixel is not None:
            h, w = app.photo_set.photos[ref].size
            self.pick(np.clip(np.array(st.pixel, np.float64), 0, [w - 1, h - 1]))
        if st.support is not None:
            if st.support in stems:
                self.sup = stems.index(st.support)
            else:
                problems.append(f"no photo `{st.support}`")
        if st.presenter is not None:
            self.presenter = st.presenter
        if st.step:
            self.start(st.step)
        elif st.step == 0:
            self.stop()
        self.md_link.content = ("Opened the prepared link." if not problems else
                                "Opened the prepared link, but " + "; ".join(problems) + ".")
        s._record("prepared", to_query(st))
