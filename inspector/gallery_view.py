"""The failure gallery in the inspector (issue 12, item 4): a "Gallery" tab beside Pixel,
Supports and Sweep.

For the shown reference it lists the ranked regions of `pipeline.gallery.build_gallery`, the
same function `crowdcam report` calls: with ground truth the missed movers (M) and the static
regions lit up (F), without it the most uncertain regions (U); each with its area, its crop
(photo and map, from crowdcam/report.py's `crop_picture`) and its diagnoses, strongest first.
With ground truth, a table above the entries says what each cue of the map says about the
reference's movers and its static pixels (`pipeline.gallery.cue_summary`, the report's table).
An entry's button explains its pixel exactly as a click on the photo does (the session's own
pixel path), and what the Pixel tab then shows of that pixel (the verdict, each support's vote,
the fusion table with every support's P(x|I_s), the best candidates' similarities and each
support's picture with its line and best candidates) appears under the entry itself: viser 1.1
cannot select a tab from the server (a tab group's and a panel's props are their tabs' labels,
icons and containers; the selected tab is the browser's own state), so the explanation comes to
the Gallery tab instead of the Gallery tab sending the user to the Pixel tab. It is the Pixel
tab's own content (Session.pixel_parts, published with the report), not a second computation.

The gallery is computed on a redrawer of its own, after the reference's pairs have finished, for
the preset's own map (its pipeline settings) at the tab's threshold; meanwhile the tab says
"computing…". It follows the reference, the preset and the threshold: each change marks what is
shown as out of date at once, and only the latest state is computed (Redrawer). A result for a
state that is no longer the tab's is never published.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import numpy as np

from pipeline.gallery import (CUE_INTRO, CUE_TITLE, CUES, FALSE_ALARM, KIND_TITLE, MISSED, UNCERTAIN, CueSummary,
                              Gallery, build_gallery, cue_summary, signed)

from . import compose, render

COMPUTING = "computing…"
MAX_PER_KIND = 5                       # as `crowdcam report --max-entries` (its default)
SLOTS = 2 * MAX_PER_KIND               # M and F with ground truth; U alone without
CROP_SIDE = 150                        # each half of an entry's picture (photo | map), px
BLANK = np.full((8, 8, 3), 255, np.uint8)
KIND_LETTER = {MISSED: "M", FALSE_ALARM: "F", UNCERTAIN: "U"}
HELP = ("The worst regions of this reference's map, ranked by area (with ground truth: **M** missed movers, "
        "**F** static regions lit up; without: **U** the most uncertain regions, by summed uncertainty), each "
        "with a first diagnosis from what the run already computed (as `crowdcam report`). The preset's own map "
        "at this tab's threshold. **Click an entry** to explain its pixel: the main view marks it, and what "
        "every support said there (its P(x|I_s), its vote, its best candidates) appears under the entry, as "
        "in the **Pixel** tab.")
OTHER_POINT = ("*Another point is explained now (a click on the photo). Click the entry again to see its "
               "evidence here.*")


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


def cue_markdown(c: CueSummary) -> str:
    """The reference's cues against its ground truth (pipeline.gallery.cue_summary), as the
    report's table has them, one row per cue."""
    rows = [f"| {CUE_TITLE[k]} | {signed(c.moving[k])} | {signed(c.static[k])} |" for k in CUES]
    return (f"**What each cue says here**: {CUE_INTRO}\n\n"
            "| cue | movers | static pixels |\n| --- | --- | --- |\n" + "\n".join(rows) +
            f"\n| P_dynamic (the map) | {c.dynamic[0]:.2f} | {c.dynamic[1]:.3f} |")


@dataclass(frozen=True)
class Slot:
    """One entry's widgets: its button, diagnoses and crop; under them, once it is opened, its
    pixel's evidence as the Pixel tab shows it (verdict, vote chart, tables, support pictures
    with their legend)."""

    btn: object
    md: object
    img: object
    ev_verdict: object
    ev_chart: object
    ev_tables: object
    ev_tiles: object
    ev_legend: object

    @property
    def evidence(self) -> tuple:
        return (self.ev_verdict, self.ev_chart, self.ev_tables, self.ev_tiles, self.ev_legend)


class GalleryView:
    """The Gallery tab of one session. key: (preset, reference, threshold) of what is shown;
    gallery: the Gallery shown (None while computing); compute_ms: server-side times of the
    builds (build_gallery plus pictures)."""

    def __init__(self, session):
        from .app import Redrawer          # app imports this module: at call time, not at import
        self.s = session
        self.key: tuple | None = None
        self.gallery: Gallery | None = None
        self.cues: CueSummary | None = None   # what each cue says about the shown reference (ground truth)
        self.opened: tuple | None = None    # (key, entry index, pixel) of the entry last opened
        self.compute_ms: list[float] = []
        self._want: tuple | None = None     # the state the tab shows now
        self._lock = threading.Lock()
        gui = session.client.gui
        with session.panel.add_tab("Gallery"):
            self.md_head = gui.add_markdown(f"Failure gallery: {COMPUTING}")
            self.md_cues = gui.add_markdown("", visible=False)     # with ground truth: cue_markdown
            self.md_explained = gui.add_markdown("")
            self.slots: list[Slot] = []
            for k in range(SLOTS):
                btn = gui.add_button(f"entry {k + 1}", visible=False, hint="explain this region's pixel (as a click "
                                                                          "on the photo there): what every support "
                                                                          "said there appears under the entry")
                md = gui.add_markdown("", visible=False)
                img = gui.add_image(render.message(""), format="jpeg", jpeg_quality=85, visible=False)
                slot = Slot(btn, md, img, gui.add_markdown("", visible=False),
                            gui.add_image(BLANK, format="png", visible=False), gui.add_markdown("", visible=False),
                            gui.add_image(BLANK, format="jpeg", jpeg_quality=85, visible=False),
                            gui.add_image(BLANK, format="png", visible=False))
                btn.on_click(lambda _ev, k=k: self.open(k))
                self.slots.append(slot)
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
        elif what == "pixel":
            self._pixel_moved()

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
        self.gallery, self.key, self.cues = None, None, None
        self.md_cues.visible = False
        self._hide_evidence()
        for slot in self.slots:
            slot.btn.visible = slot.md.visible = slot.img.visible = False

    def _hide_evidence(self) -> None:
        """No entry shows an explanation (call under the session's _pub)."""
        self.opened = None
        for slot in self.slots:
            for h in slot.evidence:
                h.visible = False

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
        cues = cue_summary(snap, ref, gt, done, dyn) if gt is not None else None
        pad = 2 * patch_length(snap.params)
        pictures = [crop_picture(rgb, dyn, threshold, e, pad, CROP_SIDE) for e in gallery.entries[:SLOTS]]
        ms = 1000 * (time.perf_counter() - t0)
        with s._pub:
            if self.state() != want or s._closed:
                return                                          # the tab moved on: a newer build follows
            self.gallery, self.key = gallery, want
            self.compute_ms = (self.compute_ms + [ms])[-50:]
            self.md_head.content = self._head(gallery, stem)
            self.cues = cues
            self.md_cues.content = cue_markdown(cues) if cues is not None else ""
            self.md_cues.visible = cues is not None
            self._hide_evidence()                               # the entries may be others now
            self.md_explained.content = ""
            for k, slot in enumerate(self.slots):
                if k < len(gallery.entries):
                    e = gallery.entries[k]
                    slot.btn.label = entry_label(e)
                    slot.md.content = entry_markdown(e)
                    slot.img.image = pictures[k]
                    slot.btn.visible = slot.md.visible = slot.img.visible = True
                else:
                    slot.btn.visible = slot.md.visible = slot.img.visible = False
        s._record("gallery", (stem, len(gallery.entries)))

    def _head(self, g: Gallery, stem: str) -> str:
        n = {k: v for k, v in g.counts.items() if v}
        if g.has_gt:
            found = f"{n.get(MISSED, 0)} missed movers and {n.get(FALSE_ALARM, 0)} static regions lit up"
        else:
            found = f"no ground truth: {n.get(UNCERTAIN, 0)} uncertain regions"
        shown = f"the {len(g.entries)} worst shown" if g.entries else "nothing to show"
        return (f"**Failure gallery of {stem}** at the threshold {g.threshold:.3f}: {found} ({shown}). "
                "Click an entry to explain its pixel: each support's evidence appears under it.")

    def _publish_text(self, want: tuple, text: str) -> None:
        with self.s._pub:
            if self.state() == want and not self.s._closed:
                self._hide_entries()
                self.md_head.content = text

    # ------------------------------------------------------------------ opening an entry
    def open(self, k: int) -> None:
        """Explain entry k's pixel, as a click on the photo there would; its evidence follows
        under the entry when the session has explained it (_show_explained)."""
        s = self.s
        g, key = self.gallery, self.key
        if g is None or key is None or k >= len(g.entries) or key[:2] != self.state()[:2]:
            return
        e = g.entries[k]
        xy = np.array(e.region.pixel, np.float64)
        if s.large is not None:                 # a support shown large: back to the map, where the pixel shows
            s.dd_large.value = s.dd_large.options[0]
        name = f"{KIND_LETTER[e.region.kind]}{e.region.rank}"
        with s._pub:
            self._hide_evidence()
            self.opened = (key, k, (float(xy[0]), float(xy[1])))
            slot = self.slots[k]
            slot.ev_verdict.content = f"**{name} opened**: pixel ({xy[0]:.0f}, {xy[1]:.0f}), {COMPUTING}"
            slot.ev_verdict.visible = True
            self.md_explained.content = f"**{name}** opened: its pixel's evidence is under the entry."
        s._record("gallery open", (s.app.stems[key[1]], name, (int(xy[0]), int(xy[1]))))
        s._set_pixel(xy)                        # the path a click on the photo takes (either view)

    def _opened_report(self):
        """The session's explanation of the opened entry's pixel, as the Pixel tab shows it:
        (slot, entry name, report, parts), or None when the session explains something else."""
        s, op = self.s, self.opened
        if op is None or self.gallery is None or op[0] != self.key or op[1] >= len(self.gallery.entries):
            return None
        rep, pp = s.report, s.pixel_parts
        if rep is None or pp is None or pp[0] is not rep or rep.ref != s.settings.ref or s.pixel is None or \
                not np.array_equal(rep.xy, np.array(op[2])) or not np.array_equal(s.pixel, rep.xy):
            return None
        e = self.gallery.entries[op[1]]
        return self.slots[op[1]], f"{KIND_LETTER[e.region.kind]}{e.region.rank}", rep, pp[1]

    def _show_explained(self) -> None:
        """The session explained a pixel: when it is the opened entry's, its evidence under the
        entry (the Pixel tab's own parts: verdict, vote chart, fusion and evidence tables, support
        pictures and their legend)."""
        s = self.s
        with s._pub:
            found = self._opened_report()
            if found is None:
                return
            slot, name, rep, parts = found
            slot.ev_verdict.content = f"**{name}**: " + parts["verdict"]
            slot.ev_chart.image = parts["chart"]
            slot.ev_tables.content = "\n\n".join(t for t in (parts["fusion"], parts["evidence"]) if t)
            slot.ev_tiles.image = parts["tiles"]
            slot.ev_legend.image = parts["legend"]
            for h in slot.evidence:
                h.visible = True
            self.md_explained.content = (f"**{name}** opened: P_dynamic **{rep.dynamic:.2f}** at its pixel; what "
                                         "every support said there is under the entry.")
        s._record("gallery explained", (name, tuple(int(v) for v in rep.xy)))

    def _pixel_moved(self) -> None:
        """Another point is being explained: the opened entry's evidence would go stale."""
        s, op = self.s, self.opened
        if op is None or s.pixel is None or np.array_equal(s.pixel, np.array(op[2])):
            return
        with s._pub:
            slot = self.slots[op[1]]
            for h in slot.evidence[1:]:
                h.visible = False
            slot.ev_verdict.content = OTHER_POINT
            self.opened = None
            self.md_explained.content = ""
