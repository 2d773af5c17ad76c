"""The reference picker (inspector/picker.py): thumbnails, one click to show a photo, its state.

The pure parts (the status style sheet, the click's value) without a browser; then Debian's
Chromium driven by Playwright on a five-photo set rendered in the test, with the inspector in
this process and its run held after the geometry (so the test sees the run still going, however
slow the machine): each thumbnail shows its photo's supports and the map's state; a click on one
makes it the reference (the server's state, the Reference dropdown and the picker's frame); its
pairs are then computed before any other photo's; every map ends "ready"; and the dropdown's
choice is framed in the picker too.

No test sleeps to wait for a state: they wait for the session's recorded events and for the
page's own state (Playwright's wait_for_function and auto-waiting locators).
"""

import re
import shutil
import threading

import pytest
from playwright.sync_api import expect

from browserkit import browser, settled, wait_event, wait_for, shown_text  # noqa: F401 (a fixture)

N_PHOTOS = 5


# ----------------------------------------------------------------------------- no browser
def test_status_css_writes_each_cell_and_frames_the_shown_photo():
    from inspector.model import RefState
    from inspector.picker import STATE_COLOURS, badge_text, status_css, summary_text
    states = [RefState(3, 3, "ready"), RefState(4, 1, "computing"), RefState(2, 0, "queued"), RefState(0, 0, "no map")]
    css = status_css(states, 1, "abc-123")
    assert '#cc-p0 .cc-badge::after { content: "ready"; }' in css
    assert '#cc-p1 .cc-badge::after { content: "computing 1/4"; }' in css
    assert '#cc-p2 .cc-sup::after { content: "2 supports"; }' in css
    assert '#cc-p3 .cc-sup::after { content: "no support"; }' in css
    assert f"#cc-p0 .cc-badge {{ background: {STATE_COLOURS['ready']}; }}" in css
    assert "#cc-p1 .cc-shown-tag { display: inline; }" in css and "#cc-p0 .cc-shown-tag" not in css
    assert 'label[for="abc-123"]' in css                       # the hidden field's row
    assert summary_text(states) == "Maps ready: 1 of 4 · computing: 1 · queued: 1 · no map: 1"
    assert badge_text(RefState(8, 5, "incomplete")) == "stopped 5/8"
    assert "cc-badge::after" not in status_css(None, 0)        # supports not known yet: the grid's "…"


def test_a_click_value_names_a_photo_or_nothing():
    from inspector.picker import parse_pick
    assert parse_pick("3|1712345678", 5) == 3
    assert parse_pick("0", 5) == 0
    for bad in ("", "5|1", "-1|2", "x|3", "3.0|1", "<script>|1"):
        assert parse_pick(bad, 5) is None


def test_thumbnails_are_made_once_small_and_in_photo_order():
    import base64

    import cv2
    import numpy as np

    from inspector.picker import THUMB_WIDTH, Thumbnails, cell_id
    rgbs = [np.full((480, 640, 3), 40 * k, np.uint8) for k in range(4)]
    th = Thumbnails(rgbs, ["a", "b<c", "d", "e"])
    assert len(th.uris) == 4 and th.build_ms >= 0
    jpeg = base64.b64decode(th.uris[1].split(",", 1)[1])
    img = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
    assert img.shape == (THUMB_WIDTH * 3 // 4, THUMB_WIDTH, 3) and abs(int(img.mean()) - 40) <= 2
    assert [th.html.index(f'id="{cell_id(k)}"') for k in range(4)] == sorted(th.html.index(f'id="{cell_id(k)}"')
                                                                           for k in range(4))
    assert "b&lt;c" in th.html and "b<c" not in th.html       # stems are escaped


# ----------------------------------------------------------------------------- the browser
@pytest.fixture(scope="module")
def small_set(tiny_set, tmp_path_factory):
    """The first five photos of the tiny square_people set, with their ground truth."""
    out = tmp_path_factory.mktemp("picker-set") / "square_five"
    photos = sorted((tiny_set / "images").glob("*"))[:N_PHOTOS]
    (out / "images").mkdir(parents=True)
    (out / "gt").mkdir()
    for p in photos:
        shutil.copy(p, out / "images" / p.name)
        gt = tiny_set / "gt" / f"{p.stem}.png"
        if gt.exists():
            shutil.copy(gt, out / "gt" / gt.name)
    return out


@pytest.fixture(scope="module")
def app(small_set, tmp_path_factory):
    from inspector.app import Inspector
    from pipeline.cache import PairCache
    from pipeline.loading import load_gts, load_set
    tmp = tmp_path_factory.mktemp("inspector-picker")
    ps = load_set(small_set, 256)
    assert len(ps.photos) == N_PHOTOS
    hold = threading.Event()             # the run waits after the geometry until the test releases it
    a = Inspector(ps, load_gts(ps), PairCache(tmp / "cache"), tmp / "out", port=0, max_side=256, workers=1,
                  hold=hold)
    a.release = hold.set
    yield a
    a.close()


def cell_words(page, k):
    """(badge, supports) as the page shows them in photo k's cell (written by the status style)."""
    return tuple(page.evaluate(
        "([k, part]) => getComputedStyle(document.querySelector('#cc-p' + k + ' .' + part), '::after').content",
        [k, part]).strip('"') for part in ("cc-badge", "cc-sup"))


def wait_cell(page, k, badge, timeout=30_000):
    page.wait_for_function(
        "([k, want]) => getComputedStyle(document.querySelector('#cc-p' + k + ' .cc-badge'), '::after').content"
        " === JSON.stringify(want)", arg=[k, badge], timeout=timeout)


def shown_tag_visible(page, k):
    return page.locator(f"#cc-p{k} .cc-shown-tag").is_visible()


def test_click_a_thumbnail_to_show_that_photo(app, browser, tmp_path):
    from inspector.picker import PICK_LABEL
    page = browser.new_context(viewport={"width": 1366, "height": 768}).new_page()
    before = set(app.sessions)
    page.goto(app.url)
    page.locator("#cc-p0 img").wait_for(timeout=60_000)
    wait_for(lambda: set(app.sessions) - before, what="the tab's session")
    tab = app.sessions[(set(app.sessions) - before).pop()]
    model = app.models["default"]
    stems = app.stems

    # the run is held after the geometry: supports known, no pair computed yet
    wait_for(lambda: model.supports is not None and tab.ref_chosen, what="the support sets")
    assert model.status == "running" and len(model.results) == 0
    first = model.first_ref
    wait_for(lambda: tab.settings.ref == first, what="the first reference shown")
    settled(tab)
    assert page.locator("#cc-p0 img").get_attribute("src").startswith("data:image/jpeg;base64,")
    assert page.locator(".cc-cell").count() == N_PHOTOS
    assert not page.get_by_label(PICK_LABEL).is_visible()          # the field a click writes to is hidden
    for k, sups in enumerate(model.supports):
        # the badge first: the page applies the style sheet that writes both words a moment after the
        # server has sent it, so the supports are read once the badge shows the held state
        want = "no map" if not sups else (f"computing 0/{len(sups)}" if k == first else "queued")
        wait_cell(page, k, want)
        badge, sup = cell_words(page, k)
        assert sup == (f"{len(sups)} supports" if len(sups) > 1 else "1 support" if sups else "no support")
    assert shown_tag_visible(page, first)
    page.screenshot(path=str(tmp_path / "picker_held.png"))

    # one click on another photo's thumbnail: it is the reference, on the server and in the page
    pick = next(k for k, s in enumerate(model.supports) if s and k != first)
    n = len(tab.events)
    page.locator(f"#cc-p{pick}").click()
    wait_event(tab, "ref", lambda v: v == stems[pick], after=n)
    assert ("picked", stems[pick]) in tab.events[n:]
    assert tab.settings.ref == pick and model.preferred == pick
    expect(page.get_by_role("combobox", name="Reference")).to_have_value(stems[pick], timeout=30_000)
    wait_cell(page, pick, f"computing 0/{len(model.supports[pick])}")
    page.locator(f"#cc-p{pick} .cc-shown-tag").wait_for(state="visible", timeout=30_000)
    assert not shown_tag_visible(page, first)
    # the same photo again: nothing changes (no second reference change)
    n = len(tab.events)
    page.locator(f"#cc-p{pick}").click()
    wait_event(tab, "picked", lambda v: v == stems[pick], after=n)
    assert not any(e[0] == "ref" for e in tab.events[n:])

    # the run goes on: the picked photo's pairs are computed before any other photo's
    app.release()
    wait_cell(page, pick, "ready", timeout=600_000)
    k_pick = len(model.supports[pick])
    assert [i for i, _j in model.order[:k_pick]] == [pick] * k_pick
    shown_text(page, re.compile(r"^Ready: \d+ pairs")).wait_for(timeout=600_000)
    settled(tab)
    for k, sups in enumerate(model.supports):
        wait_cell(page, k, "ready" if sups else "no map")
    with_map = sum(1 for s in model.supports if s)
    page.wait_for_function("(want) => getComputedStyle(document.querySelector('#cc-summary'), '::after').content"
                           " === JSON.stringify(want)", arg=f"Maps ready: {with_map} of {N_PHOTOS}"
                           + ("" if with_map == N_PHOTOS else f" · no map: {N_PHOTOS - with_map}"), timeout=30_000)
    assert tab.dyn is not None and tab.settings.ref == pick
    page.screenshot(path=str(tmp_path / "picker_ready.png"))

    # the dropdown still chooses, and the picker frames its choice
    other = next(k for k, s in enumerate(model.supports) if s and k != pick)
    n = len(tab.events)
    page.get_by_role("combobox", name="Reference").click()
    page.get_by_role("option", name=stems[other], exact=True).click()
    wait_event(tab, "ref", lambda v: v == stems[other], after=n)
    page.locator(f"#cc-p{other} .cc-shown-tag").wait_for(state="visible", timeout=30_000)
    assert not shown_tag_visible(page, pick)
    page.close()
