"""The failure gallery in the inspector (inspector/gallery_view.py) in a real browser.

Debian's Chromium driven by Playwright; the inspector runs in this process, so the test reads
what the server did (the session's recorded events and its gallery). It opens the Gallery tab,
finds the reference's ranked regions (pipeline.gallery.build_gallery's), opens one and finds its
explanation one click away: the session's pixel and pixel report are the entry's, and what every
support said there (the Pixel tab's own verdict, vote chart, tables and pictures) is under the
entry in the Gallery tab, seen there without leaving it; another entry takes it over, and a click
elsewhere on the photo says it is no longer shown. Another reference replaces the gallery (never
a stale one); without ground truth the gallery lists uncertain regions.

No test sleeps to wait for a state: they wait for recorded events and the redrawers' idle events.
"""

import re
import time
from pathlib import Path

import numpy as np
import pytest

from browserkit import browser, wait_event, wait_for, shown_text  # noqa: F401 (a fixture)
from conftest import SAMPLE_SETS


def settled(session):
    for _ in range(1000):
        assert session.slow.wait_idle(120) and session.fast.wait_idle(60) and session.gallery.draw.wait_idle(120)
        if session.slow.idle() and session.fast.idle() and session.gallery.draw.idle():
            return
    raise AssertionError("the tab never settled")


def gallery_ready(tab):
    g = tab.gallery
    return g.gallery is not None and g.key == g.state()


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("inspector-gallery")


def make_app(cache_dir, with_gt: bool, sub: str):
    from inspector.app import Inspector
    from pipeline.cache import PairCache
    from pipeline.loading import load_gts, load_set
    ps = load_set(SAMPLE_SETS / "tabletop_ball", 256)
    return Inspector(ps, load_gts(ps) if with_gt else {}, PairCache(cache_dir / "cache"), cache_dir / sub,
                     port=0, max_side=256, workers=1)


def open_tab(browser, app, viewport=(1366, 768)):
    page = browser.new_context(viewport={"width": viewport[0], "height": viewport[1]}).new_page()
    before = set(app.sessions)
    page.goto(app.url)
    shown_text(page, "Threshold", exact=True).first.wait_for(timeout=60_000)
    wait_for(lambda: set(app.sessions) - before, what="the tab's session")
    tab = app.sessions[(set(app.sessions) - before).pop()]
    shown_text(page, re.compile(r"^Ready: \d+ pairs")).wait_for(timeout=900_000)
    close = page.locator(".mantine-Notification-closeButton")     # the "software WebGL" toast over the canvas
    if close.count():
        close.first.click()
    settled(tab)
    return page, tab


def test_gallery_entry_opens_its_explanation(browser, cache_dir):
    from inspector.gallery_view import KIND_LETTER, entry_label
    from pipeline.gallery import FALSE_ALARM, MISSED
    app = make_app(cache_dir, True, "out")
    try:
        page, tab = open_tab(browser, app)
        wait_for(lambda: gallery_ready(tab), 300, "the gallery")
        ref, stem = tab.settings.ref, app.stems[tab.settings.ref]
        g = tab.gallery.gallery
        assert g.stem == stem and g.has_gt and g.entries
        assert {e.region.kind for e in g.entries} <= {MISSED, FALSE_ALARM}
        assert abs(g.threshold - tab.settings.threshold) < 1e-6

        page.get_by_role("tab", name="Gallery").click()
        shown_text(page, f"Failure gallery of {stem}").first.wait_for(timeout=10_000)
        # what each cue says about this reference against its ground truth, as the report's table
        c = tab.gallery.cues
        assert c is not None and c.stem == stem and c.n_moving > 0 and np.isfinite(c.moving["strips"])
        shown_text(page, "What each cue says here", exact=False).first.wait_for(timeout=10_000)
        e = g.entries[0]
        btn = page.get_by_role("button", name=entry_label(e))
        btn.wait_for(timeout=10_000)
        x, y = e.region.pixel
        assert e.region.full_mask(app.photo_set.photos[ref].size)[y, x]     # the pixel is the region's
        page.screenshot(path=str(cache_dir / "gallery.png"))

        # one click: the entry's pixel explained, by the path a click on the photo takes
        n = len(tab.events)
        btn.click()
        wait_event(tab, "explained", after=n)
        settled(tab)
        names = [ev[0] for ev in tab.events[n:]]
        assert names.index("gallery open") < names.index("pixel") < names.index("explained")
        assert ("pixel", (float(x), float(y))) in tab.events[n:]
        assert tab.settings.ref == ref
        np.testing.assert_array_equal(tab.pixel, [x, y])
        rep = tab.report
        assert rep is not None and rep.ref == ref
        np.testing.assert_array_equal(rep.xy, [x, y])
        # the explanation under the entry, in the Gallery tab: the Pixel tab's own content for
        # the session's report (published with it, not computed again), every support in it
        wait_event(tab, "gallery explained", lambda v: v[1] == (x, y), after=n)
        assert len(rep.evidence) > 0
        report, parts = tab.pixel_parts
        assert report is rep
        slot = tab.gallery.slots[0]
        assert all(h.visible for h in slot.evidence)
        assert not any(h.visible for other in tab.gallery.slots[1:] for h in other.evidence)
        assert slot.ev_verdict.content.endswith(tab.md_pixel.content)
        assert tab.md_fusion.content in slot.ev_tables.content and tab.md_evidence.content in slot.ev_tables.content
        assert np.array_equal(slot.ev_chart.image, tab.img_fusion.image)
        assert np.array_equal(slot.ev_tiles.image, tab.img_evidence.image)
        assert np.array_equal(slot.ev_legend.image, tab.img_lines.image)
        for e_ in rep.evidence:                      # each support's P(x|I_s) row, in the tables
            assert f"| {app.stems[e_.sup]} (" in slot.ev_tables.content
        # seen without leaving the Gallery tab (the Pixel tab, which says the same, is hidden)
        verdict = re.compile(rf"{KIND_LETTER[e.region.kind]}{e.region.rank}: Pixel \({x}, {y}\)\s*of {stem}: P_dynamic {rep.dynamic:.2f}")
        shown_text(page, verdict).locator("visible=true").first.wait_for(timeout=10_000)
        first_sup = app.stems[rep.evidence[0].sup]
        page.get_by_role("cell", name=re.compile(rf"^{first_sup} \(")).locator("visible=true").first.wait_for(
            timeout=10_000)
        page.screenshot(path=str(cache_dir / "gallery_opened.png"))

        # another entry takes the explanation over
        if len(g.entries) > 1:
            e2 = g.entries[1]
            n = len(tab.events)
            page.get_by_role("button", name=entry_label(e2)).click()
            wait_event(tab, "gallery explained", lambda v: v[1] == tuple(e2.region.pixel), after=n)
            settled(tab)
            assert all(h.visible for h in tab.gallery.slots[1].evidence)
            assert not any(h.visible for h in slot.evidence)
            np.testing.assert_array_equal(tab.report.xy, list(e2.region.pixel))
            slot, (x, y) = tab.gallery.slots[1], e2.region.pixel

        # a click elsewhere on the photo: the entry no longer claims to show its pixel
        box = page.locator("canvas").first.bounding_box()
        n = len(tab.events)
        page.mouse.click(box["x"] + box["width"] * 0.45, box["y"] + box["height"] * 0.55)
        wait_event(tab, "explained", after=n)
        settled(tab)
        if not np.array_equal(tab.pixel, [x, y]):
            assert slot.ev_verdict.visible and "Another point is explained now" in slot.ev_verdict.content
            assert not any(hd.visible for hd in slot.evidence[1:])

        # another reference: the old gallery goes at once, the new one is the new reference's
        other = next(i for i, s in enumerate(app.stems) if i != ref and s in app.gts)
        n = len(tab.events)
        tab.dd_ref.value = app.stems[other]          # as the dropdown does (fires _on_ref)
        wait_event(tab, "gallery", lambda v: v[0] == app.stems[other], after=n, timeout=300)
        settled(tab)
        assert tab.gallery.key[1] == other and tab.gallery.gallery.stem == app.stems[other]
        page.get_by_role("tab", name="Gallery").click()
        shown_text(page, f"Failure gallery of {app.stems[other]}").first.wait_for(timeout=10_000)
        assert tab.gallery.compute_ms
    finally:
        for ctx in browser.contexts:     # no page left to reconnect to a later app on the same port
            ctx.close()
        app.close()


def test_gallery_without_ground_truth_lists_uncertain_regions(browser, cache_dir):
    from inspector.gallery_view import entry_label
    from pipeline.gallery import UNCERTAIN
    app = make_app(cache_dir, False, "out-nogt")
    try:
        page, tab = open_tab(browser, app)
        wait_for(lambda: gallery_ready(tab), 300, "the gallery")
        g = tab.gallery.gallery
        assert not g.has_gt
        assert all(e.region.kind == UNCERTAIN for e in g.entries)
        assert tab.gallery.cues is None and not tab.gallery.md_cues.visible     # no ground truth: no cue table
        page.get_by_role("tab", name="Gallery").click()
        shown_text(page, "no ground truth", exact=False).first.wait_for(timeout=10_000)
        if g.entries:
            e = g.entries[0]
            n = len(tab.events)
            page.get_by_role("button", name=entry_label(e)).click()
            wait_event(tab, "explained", after=n)
            settled(tab)
            np.testing.assert_array_equal(tab.report.xy, list(e.region.pixel))
    finally:
        for ctx in browser.contexts:     # no page left to reconnect to a later app on the same port
            ctx.close()
        app.close()


# ----------------------------------------------------------------------------- presets side by side
def presets_state(tab):
    return {p: v[3] for p, v in tab.presets.shown.items()}


def test_presets_side_by_side_stay_in_sync(browser, cache_dir):
    from inspector.side_by_side import PRESETS_SHOWN
    app = make_app(cache_dir, True, "out-presets")
    try:
        page, tab = open_tab(browser, app)
        pp = tab.presets
        pp.draw.wait_idle(120)
        wait_for(lambda: presets_state(tab).get("default") == "map", 120, "the default panel")
        ref = tab.settings.ref
        page.get_by_role("tab", name="Presets").click()
        for p in ("paper", "peer-homography"):             # not run yet: the panel says so and offers it
            assert presets_state(tab)[p] == "not run"
            shown_text(page, f"{p}: not computed yet", exact=False).first.wait_for(timeout=10_000)
        for p in ("paper", "peer-homography"):             # one run at a time (the button waits)
            n = len(tab.events)
            page.get_by_role("button", name=f"Compute {p}", exact=True).click()
            wait_event(tab, "presets compute", lambda v, p=p: v == p, after=n)
            wait_for(lambda p=p: presets_state(tab).get(p) == "map", 600, f"the {p} map")
            # the shown photo's map comes before the run ends, and the next button waits for the end
            wait_for(lambda p=p: app.models[p].status == "done", 900, f"the {p} run")
        pp.draw.wait_idle(120)
        for p in PRESETS_SHOWN:                              # each with its Jaccard (ground truth)
            shown_text(page, re.compile(rf"^{re.escape(p)}: threshold .* Jaccard \d\.\d{{3}}")).first.wait_for(
                timeout=10_000)
        assert all(app.models[p].error is None for p in PRESETS_SHOWN)

        # a click on the photo: the same pixel marked in all three panels
        box = page.locator("canvas").first.bounding_box()
        n = len(tab.events)
        page.mouse.click(box["x"] + box["width"] * 0.45, box["y"] + box["height"] * 0.55)
        wait_event(tab, "presets shown", lambda v: v[1] is not None, after=n)
        settled(tab)
        pp.draw.wait_idle(120)
        px = (float(tab.pixel[0]), float(tab.pixel[1]))
        assert all(v[0] == ref and v[1] == px for v in pp.shown.values())
        shown_text(page, f"point ({px[0]:.0f}, {px[1]:.0f}) marked in all three").wait_for(timeout=10_000)

        # zoomed: the same window around the same pixel in all three
        n = len(tab.events)
        page.get_by_label("Zoom on the clicked point").check()
        wait_event(tab, "presets shown", after=n)
        pp.draw.wait_idle(120)
        windows = {v[2] for v in pp.shown.values()}
        assert len(windows) == 1 and None not in windows
        x0, y0, x1, y1 = windows.pop()
        assert x0 <= px[0] < x1 and y0 <= px[1] < y1

        # a gallery entry opened: its pixel in all three
        wait_for(lambda: gallery_ready(tab), 300, "the gallery")
        e = tab.gallery.gallery.entries[0]
        page.get_by_role("tab", name="Gallery").click()
        n = len(tab.events)
        from inspector.gallery_view import entry_label
        page.get_by_role("button", name=entry_label(e)).click()
        want = (float(e.region.pixel[0]), float(e.region.pixel[1]))
        wait_event(tab, "presets shown", lambda v: v[1] == want, after=n)
        pp.draw.wait_idle(120)
        assert all(v[1] == want for v in pp.shown.values())
        page.get_by_role("tab", name="Presets").click()
        page.screenshot(path=str(cache_dir / "presets.png"))
    finally:
        for ctx in browser.contexts:     # no page left to reconnect to a later app on the same port
            ctx.close()
        app.close()
