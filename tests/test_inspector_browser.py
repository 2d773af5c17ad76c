"""`crowdcam inspect` in a real browser: Debian's Chromium driven by Playwright.

The inspector runs in this process (so the test can read what the server computed); the browser
opens the page while pairs are still being computed, changes the reference, unticks a support,
moves the threshold, clicks a pixel, downloads the map, and a second tab keeps its own state.
Screenshots are kept under the pytest temp dir (printed at the end).
"""

import re
import threading
import time
from pathlib import Path
from urllib.parse import urlparse

import numpy as np
import pytest

from conftest import SAMPLE_SETS

CHROMIUM = "/usr/bin/chromium"
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
        "--disable-background-networking", "--disable-component-update", "--disable-sync",
        "--use-angle=swiftshader", "--enable-unsafe-swiftshader"]


def wait_for(pred, timeout=60.0, what="condition"):
    t0 = time.time()
    while time.time() - t0 < timeout:
        if pred():
            return
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


def settled(session):
    """Both redrawers idle (twice, so a draw that queued another one has finished too)."""
    for _ in range(2):
        assert session.fast.wait_idle(60) and session.slow.wait_idle(120)
        time.sleep(0.2)


@pytest.fixture(scope="module")
def shots(tmp_path_factory):
    d = tmp_path_factory.mktemp("inspector-screenshots")
    yield d
    print(f"\ninspector screenshots: {d}")


@pytest.fixture(scope="module")
def app(tmp_path_factory):
    from inspector.app import Inspector
    from pipeline.cache import PairCache
    from pipeline.loading import load_gts, load_set
    tmp = tmp_path_factory.mktemp("inspector")
    ps = load_set(SAMPLE_SETS / "tabletop_ball", 256)
    # an empty cache and a gate: the run holds after the geometry until the test releases it,
    # so it is still going when the page opens, however slow the browser is to start
    hold = threading.Event()
    a = Inspector(ps, load_gts(ps), PairCache(tmp / "cache"), tmp / "out",
                  port=0, max_side=256, workers=1, hold=hold)
    a.release = hold.set
    yield a
    a.close()


@pytest.fixture(scope="module")
def browser():
    from playwright.sync_api import sync_playwright
    assert Path(CHROMIUM).exists(), "Debian's chromium is needed (make test installs it)"
    with sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=CHROMIUM, headless=True, args=ARGS)
        yield b
        b.close()


def open_tab(browser, app, hosts):
    ctx = browser.new_context(viewport={"width": 1500, "height": 950}, accept_downloads=True)
    page = ctx.new_page()
    page.on("request", lambda r: hosts.add(urlparse(r.url).hostname) if r.url.startswith(("http", "ws")) else None)
    before = set(app.sessions)
    page.goto(app.url)
    page.wait_for_selector("text=Threshold", timeout=60_000)
    wait_for(lambda: set(app.sessions) - before, what="the tab's session")
    return page, app.sessions[(set(app.sessions) - before).pop()]


def set_number(page, slider, value: str) -> None:
    """Type into a slider's number box (arrow keys on the thumb would also orbit the 3-D view)."""
    box = page.locator(f'[id="{slider._impl.uuid}"]').locator("xpath=../..").locator("input.mantine-NumberInput-input")
    box.fill(value)
    box.press("Enter")


def canvas_shot(page, path):
    return page.locator("canvas").first.screenshot(path=str(path))


def test_inspector_in_a_browser(app, browser, shots, tmp_path):
    hosts: set = set()
    page, tab = open_tab(browser, app, hosts)
    model = app.models["default"]

    # 1. usable at once: progress while pairs are computed, then the maps
    assert model.status in ("waiting", "running"), "the run finished before the page opened"
    page.get_by_text(re.compile(r"(Finding features|Estimating geometry|Matching pairs|Starting)")).first.wait_for(
        timeout=30_000)
    page.screenshot(path=str(shots / "0_progress.png"))
    app.release()
    page.get_by_text(re.compile(r"^Ready: \d+ pairs")).wait_for(timeout=300_000)
    settled(tab)
    snap = model.snapshot()
    assert tab.settings.ref == model.first_ref                 # the photo with most supports first
    a = canvas_shot(page, shots / "1_ready.png")

    # 2. another reference (one with at least two supports)
    stems = app.stems
    ref = next(i for i, s in enumerate(snap.supports) if len(s) >= 2 and i != tab.settings.ref)
    page.get_by_role("combobox", name="Reference").click()
    page.get_by_role("option", name=stems[ref], exact=True).click()
    wait_for(lambda: tab.settings.ref == ref, what="the reference change")
    settled(tab)
    b = canvas_shot(page, shots / "2_reference.png")
    assert a != b

    # 3. untick a support: the map is Eq. 3 over the others
    sups = snap.supports[ref]
    off = sups[0]
    page.get_by_label(re.compile(rf"^{stems[off]}")).uncheck()
    wait_for(lambda: off not in tab.settings.supports, what="the support toggle")
    settled(tab)
    want = snap.dynamic_prob(ref, [j for j in sups if j != off], tab.settings.params())
    np.testing.assert_allclose(tab.dyn, want, atol=1e-5)
    c = canvas_shot(page, shots / "3_support_off.png")
    assert c != b

    # 4. the threshold, through its number box
    set_number(page, tab.sl_thr, "0.3")
    wait_for(lambda: abs(tab.settings.threshold - 0.3) < 1e-9, what="the threshold")
    settled(tab)
    d = canvas_shot(page, shots / "4_threshold.png")
    assert d != c
    assert "Jaccard at 0.30" in tab.md_eval.content
    assert tab.score is not None and 0.0 <= tab.score.at_threshold <= tab.score.best <= 1.0

    # 5. click the middle of the photo: the evidence behind that pixel
    box = page.locator("canvas").first.bounding_box()
    page.mouse.click(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    wait_for(lambda: any(e[0] == "explained" for e in tab.events), what="the pixel explanation")
    settled(tab)
    u, v = tab.pixel
    h, w = app.photo_set.photos[ref].size
    assert abs(u - w / 2) < 0.1 * w and abs(v - h / 2) < 0.1 * h     # the camera looks straight at it
    rep = tab.report
    assert [e.sup for e in rep.evidence] == [j for j in sups if j != off]
    page.get_by_role("tab", name="Pixel").click()
    page.get_by_text(re.compile(r"Pixel \(\d+, \d+\)")).wait_for(timeout=10_000)
    page.get_by_text(f"{rep.dynamic:.2f}", exact=True).first.wait_for(timeout=10_000)
    page.screenshot(path=str(shots / "5_pixel.png"))
    page.get_by_role("tab", name="Sweep").click()
    page.screenshot(path=str(shots / "6_sweep.png"))

    # 6. export: a browser download and files in the output folder
    with page.expect_download() as dl:
        page.get_by_role("button", name="Download map (.npy)").click()
    path = tmp_path / "map.npy"
    dl.value.save_as(path)
    from pipeline.output import to_original
    np.testing.assert_allclose(np.load(path), to_original(tab.dyn, app.photo_set.photos[ref]), atol=1e-6)
    page.get_by_role("button", name="Save to output folder").click()
    wait_for(lambda: any(e[0] == "saved" for e in tab.events), what="the saved files")
    for suffix in ("_dynamic.npy", "_mask.png", "_overlay.jpg", "_settings.json"):
        assert (app.out_dir / f"{stems[ref]}{suffix}").is_file()

    # 7. a second tab keeps its own reference, supports and threshold
    page2, tab2 = open_tab(browser, app, hosts)
    page2.get_by_text(re.compile(r"^Ready: \d+ pairs")).wait_for(timeout=60_000)
    assert tab2.settings.ref == model.first_ref != ref
    assert tab2.settings.threshold == 0.5
    set_number(page2, tab2.sl_thr, "0.7")
    wait_for(lambda: abs(tab2.settings.threshold - 0.7) < 1e-9, what="the second tab's threshold")
    settled(tab2)
    page2.screenshot(path=str(shots / "7_second_tab.png"))
    assert tab.settings.threshold == 0.3 and tab.settings.ref == ref and off not in tab.settings.supports
    assert page.get_by_role("slider").first.get_attribute("aria-valuenow") == "0.3"
    n = len(app.sessions)
    page2.context.close()
    wait_for(lambda: len(app.sessions) == n - 1, what="the closed tab's cleanup")
    assert not tab2.fast._thread.is_alive() and not tab2.slow._thread.is_alive()

    # 8. Open in Rerun: records this reference into the loopback viewer and links to it
    page.get_by_role("button", name="Open in Rerun").click()
    wait_for(lambda: any(e[0] == "rerun" for e in tab.events), timeout=120, what="the Rerun recording")
    url = next(e[1] for e in tab.events if e[0] == "rerun")
    assert urlparse(url).hostname == "127.0.0.1"
    page.get_by_role("link", name="open the Rerun viewer").wait_for(timeout=10_000)
    import urllib.request
    assert urllib.request.urlopen(url, timeout=10).status == 200
    page.screenshot(path=str(shots / "8_rerun_link.png"))

    assert hosts <= {"127.0.0.1"}, hosts               # nothing outside this machine
