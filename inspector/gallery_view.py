"""The failure gallery in the inspector (issue 12, item 4): a "Gallery" tab beside Pixel,
Supports and Sweep.

For the shown reference it lists the ranked regions of `pipeline.gallery.build_gallery`, the
same function `crowdcam report` calls: with ground truth the missed movers (M) and the static
regions lit up (F), without it the most uncertain regions (U); each with its area, its crop
(photo and map, from crowdcam/report.py's `crop_picture`) and its diagnoses, strongest first.
An entry's button explains its pixel exactly as a click on the photo does (the session's own
pixel path), and the verdict is repeated under the buttons (the evidence is in the Pixel tab).

The gallery is computed on a redrawer of its own, after the reference's pairs have finished, for
the preset's own map (its pipeline settings) at the tab's threshold; meanwhile the tab says
"computing…". It follows the reference, the preset and the threshold: each change marks what is
shown as out of date at once, and only the latest state is computed (Redrawer). A result for a
state that is no longer the tab's is never published.
"""

from __future__ import annotations

import threading
import time

import numpy as np

from pipeline.gallery import FALSE_ALARM, KIND_TITLE, MISSED, UNCERTAIN, Gallery, build_gallery

from . import compose, render

COMPUTING = "computing…"
MAX_PER_KIND = 5                       # as `crowdcam report --max-entries` (its default)
SLOTS = 2 * MAX_PER_KIND               # M and F with ground truth; U alone without
CROP_SIDE = 150                        # each half of an entry's picture (photo | map), px
KIND_LETTER = {MISSED: "M", FALSE_ALARM: "F", UNCERTAIN: "U"}
HELP = ("The worst regions of this reference's map, ranked by area (with ground truth: **M** missed movers, "
        "**F** static regions lit up; without: **U** the most uncertain regions, by summed uncertainty), each "
        "with a first diagnosis from what the run already computed (as `crowdcam report`). The preset's own map "
        "at this tab's threshold. **Click an entry** to explain its pixel (the main view marks it; the "
        "**Pixel** tab holds each support's evidence).")


def entry_label(e) -> str:
    """The entry's button: 'M1 · missed mover · 812 px · no support sees it'."""
    r = e.region
    return f"{KIND_LETTER[r.kind]}{r.rank} · {KIND_TITLE[r.kind]} · {r.area} px · {e.headline.title}"


def entry_markdown(e) -> str:
    """The entry's diagnoses, strongest first, with their figures (one line each)."""
    r = e.region
    head = f"Pixel ({r.pixel[0]}, {r.pixel[1]}), {r.share:.1%} of the photo, mean P {r.mean_p:.2f}"
    if r.kind == MISSED and r.object_area:
        head += f"; part of a mover of {r.object_area} px, {r.object_found:.0%} of it found"
    lines = [head + "."]
    for d in e.diagnoses[:3]:
        lines.append(f"- **{d.title}** ({d.strength:.2f}): {d.detail}")
    return "\n".join(lines)


class GalleryView:
    """The Gallery tab of one session. key: (preset, reference, threshold) of what is shown;
    gallery: the Gallery shown (None while computing); compute_ms: server-side times of the
    builds (build_gallery plus pictures)."""

    def __init__(self, session):
        from .app import Redrawer          # app imports this module: at call time, not at import
        self.s = session
        self.key: tuple | None = None
        self.gallery: Gallery | None = None
        self.opened: tuple | None = None    # (key, entry index, pixel) of the entry last opened
        self.compute_ms: list[float] = []
        self._want: tuple | None = None     # the state the tab shows now
        self._lock = threading.Lock()
        gui = session.client.gui
        with session.panel.add_tab("Gallery"):
            self.md_head = gui.add_markdown(f"Failure gallery: {COMPUTING}")
            self.md_explained = gui.add_markdown("")
            self.slots = []
            for k in range(SLOTS):
                btn = gui.add_button(f"entry {k + 1}", visible=False, hint="explain this region's pixel (as a click "
                                                                          "on the photo there)")
                md = gui.add_markdown("", visible=False)
                img = gui.add_image(render.message(""), format="jpeg", jpeg_quality=85, visible=False)
                btn.on_click(lambda _ev, k=k: self.open(k))
                self.slots.append((btn, md, img))
            with gui.add_folder("About the gallery", expand_by_default=False):
                gui.add_markdown(HELP)
        self.draw = Redrawer(f"tab{session.client.client_id}-gallery", self._build)
        self.request()

    # ------------------------------------------------------------------ state
    def state(self) -> tuple:
        st = self.s.settings
        return (st.preset, st.ref, round(float(st.threshold), 4))

    def on_event(self, what: str, value) -> None:
        """The session's recorded events: a new reference, preset or threshold, or a redrawn sweep
        (which follows every pair of the reference that finishes) may change the gallery."""
        if what in ("ref", "preset", "settings", "sweep"):
            self.request()
        elif what == "explained":
            self._show_explained()

    def request(self) -> None:
        want = self.state()
        with self._lock:
            changed = want != self._want
            self._want = want
        if changed:
            with self.s._pub:
                if self.key is None or self.key[:2] != want[:2]:     # another photo or preset: nothing of the old
                    self._hide_entries()
                    self.md_explained.content = ""
                    self.md_head.content = f"Failure gallery of {self.s.app.stems[want[1]]}: {COMPUTING}"
                elif self.key != want:
                    self.md_head.content = (f"Failure gallery of {self.s.app.stems[want[1]]}: updating for the "
                                            f"threshold {want[2]:.3f} ({COMPUTING})")
        self.draw.request("gallery")

    def close(self) -> None:
        self.draw.stop()

    def _hide_entries(self) -> None:
        self.gallery, self.key = None, None
        for btn, md, img in self.slots:
            btn.visible = md.visible = img.visible = False

    # ------------------------------------------------------------------ computing (own thread)
    def _build(self, _what: set[str]) -> None:
        s, app = self.s, self.s.app
        want = self.state()
        if want == self.key:
            return
        preset, ref, threshold = want
        stem = app.stems[ref]
        model = app.model(preset)
        snap = model.snapshot()
        if snap is None:
            return                                              # the sweep event after the geometry asks again
        sups = list(snap.supports[ref])
        done = [j for j in sups if (ref, j) in snap.pair_results]
        if not sups:
            self._publish_text(want, f"No gallery for {stem}: it has no supports.")
            return
        if len(done) < len(sups) and model.status in ("waiting", "running"):
            self._publish_text(want, f"Failure gallery of {stem}: {COMPUTING} (waiting for its pairs, "
                                     f"{len(done)} of {len(sups)} ready)")
            return
        if not done:
            self._publish_text(want, f"No gallery for {stem}: none of its pairs was computed.")
            return
        t0 = time.perf_counter()
        gt = app.gts.get(stem)
        gallery = build_gallery(snap, ref, gt, threshold, MAX_PER_KIND)
        from crowdcam.report import crop_picture
        from pipeline.matching import patch_length
        rgb = app.photo_set.photos[ref].rgb
        dyn = snap.dynamic_prob(ref, done)
        pad = 2 * patch_length(snap.params)
        pictures = [crop_picture(rgb, dyn, threshold, e, pad, CROP_SIDE) for e in gallery.entries[:SLOTS]]
        ms = 1000 * (time.perf_counter() - t0)
        with s._pub:
            if self.state() != want or s._closed:
                return                                          # the tab moved on: a newer build follows
            self.gallery, self.key = gallery, want
            self.compute_ms = (self.compute_ms + [ms])[-50:]
            self.md_head.content = self._head(gallery, stem)
            for k, (btn, md, img) in enumerate(self.slots):
                if k < len(gallery.entries):
                    e = gallery.entries[k]
                    btn.label = entry_label(e)
                    md.content = entry_markdown(e)
                    img.image = pictures[k]
                    btn.visible = md.visible = img.visible = True
                else:
                    btn.visible = md.visible = img.visible = False
        s._record("gallery", (stem, len(gallery.entries)))

    def _head(self, g: Gallery, stem: str) -> str:
        n = {k: v for k, v in g.counts.items() if v}
        if g.has_gt:
            found = f"{n.get(MISSED, 0)} missed movers and {n.get(FALSE_ALARM, 0)} static regions lit up"
        else:
            found = f"no ground truth: {n.get(UNCERTAIN, 0)} uncertain regions"
        shown = f"the {len(g.entries)} worst shown" if g.entries else "nothing to show"
        return (f"**Failure gallery of {stem}** at the threshold {g.threshold:.3f}: {found} ({shown}). "
                "Click an entry to explain its pixel.")

    def _publish_text(self, want: tuple, text: str) -> None:
        with self.s._pub:
            if self.state() == want and not self.s._closed:
                self._hide_entries()
                self.md_head.content = text

    # ------------------------------------------------------------------ opening an entry
    def open(self, k: int) -> None:
        """Explain entry k's pixel, as a click on the photo there would."""
        s = self.s
        g, key = self.gallery, self.key
        if g is None or key is None or k >= len(g.entries) or key[:2] != self.state()[:2]:
            return
        e = g.entries[k]
        xy = np.array(e.region.pixel, np.float64)
        if s.large is not None:                 # a support shown large: back to the map, where the pixel shows
            s.dd_large.value = s.dd_large.options[0]
        self.opened = (key, k, (float(xy[0]), float(xy[1])))
        with s._pub:
            self.md_explained.content = (f"**{KIND_LETTER[e.region.kind]}{e.region.rank}** opened: pixel "
                                         f"({xy[0]:.0f}, {xy[1]:.0f}), {COMPUTING}")
        s._record("gallery open", (s.app.stems[key[1]], f"{KIND_LETTER[e.region.kind]}{e.region.rank}",
                                   (int(xy[0]), int(xy[1]))))
        s._set_pixel(xy)                        # the path a click on the photo takes (either view)

    def _show_explained(self) -> None:
        s, op = self.s, self.opened
        rep = s.report
        if op is None or rep is None or rep.ref != s.settings.ref or s.pixel is None or \
                not np.array_equal(rep.xy, np.array(op[2])) or not np.array_equal(s.pixel, rep.xy):
            return
        e = self.gallery.entries[op[1]] if self.gallery is not None and op[1] < len(self.gallery.entries) else None
        name = f"{KIND_LETTER[e.region.kind]}{e.region.rank}: " if e is not None else ""
        text = (name + compose.verdict_markdown(rep, s.app.stems[rep.ref], s.settings.threshold) +
                " Each support's evidence: the **Pixel** tab.")
        with s._pub:
            self.md_explained.content = text
