"""The inspector under attack (issue 14, item 5): a request for anything but the page's own
assets is 404; a run that fails inside the inspector (its workers killed, or an exception such
as a full disk) says so in the page, and the server goes on serving and its tabs on working.

The requests are sent as raw bytes over a socket (bench/stress.py's http_status), so no client
normalises `/../` or `%2e%2e`. Nothing here waits on time: the tests wait for the states the
server records (model status, session events) and for Playwright's locators. The ten-tab load
and the timings are measured by bench/stress.py (`make stress`), not asserted here.
"""

import os
import re
import threading
from pathlib import Path


from browserkit import browser, wait_for, shown_text  # noqa: F401 (a fixture)
from conftest import ROOT, SAMPLE_SETS
from bench.stress import OWN_PAGE, http_status, outside_paths

SET = SAMPLE_SETS / "tabletop_ball"


def inspector(tmp: Path, cache: Path, **kw):
    from inspector.app import Inspector
    from pipeline.cache import PairCache
    from pipeline.loading import load_gts, load_set
    ps = load_set(SET, 160)
    return Inspector(ps, load_gts(ps), PairCache(cache), tmp / "out", port=0, max_side=160, **kw)


def open_tab(browser, app):
    page = browser.new_context(viewport={"width": 1280, "height": 720}).new_page()
    before = set(app.sessions)
    page.goto(app.url)
    shown_text(page, "Threshold", exact=True).first.wait_for(timeout=60_000)
    wait_for(lambda: set(app.sessions) - before, what="the tab's session")
    return page, app.sessions[(set(app.sessions) - before).pop()]


def test_paths_outside_the_page_are_404(tmp_path):
    """Traversal (plain, encoded, double-encoded, backslashes, overlong UTF-8), absolute paths,
    viser's sources beside its page, the set's photos, ground truth and cameras (by name, by
    relative and by absolute path), the cache and the output folder: 404, every one."""
    hold = threading.Event()                # never released: the run waits after its geometry
    app = inspector(tmp_path, tmp_path / "cache", workers=1, hold=hold)
    try:
        port = app.server.get_port()
        for t in OWN_PAGE:
            status, body = http_status(port, t)
            assert status == 200 and b"<html" in body.lower()
        targets = outside_paths(SET, [app.cache.root, app.out_dir, ROOT / "README.md", ROOT / "inspector" / "app.py"])
        assert len(targets) > 50
        served = [(t, s) for t in targets if (s := http_status(port, t)[0]) != 404]
        assert served == []
        assert http_status(port, b"/")[0] == 200                       # and it still serves its page
    finally:
        app.close()


def test_a_run_that_raises_says_so_and_the_server_lives(tmp_path, browser, monkeypatch):
    """An exception in the run (here the disk fills while the cache is written) is one line in
    every tab; new tabs still open, and their controls still answer."""
    import errno

    from inspector import model as model_mod

    def full_disk(*a, **kw):
        raise OSError(errno.ENOSPC, "No space left on device", str(tmp_path / "cache"))
    monkeypatch.setattr(model_mod, "detect_set", full_disk)
    app = inspector(tmp_path, tmp_path / "cache", workers=1)
    try:
        m = app.models["default"]
        wait_for(lambda: m.status == "failed", what="the failed run")
        assert "No space left on device" in m.error
        for _ in range(2):                              # the tab open before and one opened after
            page, tab = open_tab(browser, app)
            shown_text(page, re.compile(r"^Cannot compute the default preset")).wait_for(timeout=60_000)
            shown_text(page, re.compile(r"No space left on device")).first.wait_for(timeout=10_000)
            assert "Traceback" not in page.evaluate("() => document.body.innerText")
        n = len(tab.events)
        box = page.locator(f'[id="{tab.sl_thr._impl.uuid}"]').locator("xpath=../..") \
            .locator("input.mantine-NumberInput-input")
        box.fill("0.3")
        box.press("Enter")
        wait_for(lambda: any(e[0] == "settings" and abs(e[1].threshold - 0.3) < 1e-9 for e in tab.events[n:]),
                 what="the tab's threshold")
        assert tab.fast.wait_idle(60)
        assert http_status(app.server.get_port(), b"/")[0] == 200
        page.context.close()
    finally:
        app.close()


def test_workers_killed_in_the_inspector_say_so_and_the_server_lives(tmp_path, browser, monkeypatch):
    """Workers killed twice on one pair (the out-of-memory killer, as run._fault_injection does
    it) end the run with one line in the page; the server and the tab go on."""
    # the pair order of this set: a first inspector, held after its geometry (then in the cache)
    hold = threading.Event()
    app = inspector(tmp_path, tmp_path / "cache", preset="paper", workers=1, hold=hold)
    m = app.models["paper"]
    wait_for(lambda: m.supports is not None, 300, "the support sets")
    i, j = m.first_ref, m.supports[m.first_ref][0]
    app.close()
    # spawned workers read the fault from the environment; the geometry comes from the cache, so
    # the pool is first started for the pairs, with the fault in place
    monkeypatch.setenv("CROWDCAM_FAULT", f"kill:{i},{j}")
    app = inspector(tmp_path, tmp_path / "cache", preset="paper", workers=2)
    try:
        m = app.models["paper"]
        page, tab = open_tab(browser, app)
        wait_for(lambda: m.status in ("done", "failed"), 600, "the run's end")
        assert m.status == "failed" and "died twice" in m.error, m.error
        shown_text(page, re.compile(r"^Cannot compute the paper preset")).wait_for(timeout=60_000)
        shown_text(page, re.compile(r"died twice while computing the pair")).first.wait_for(timeout=10_000)
        assert "Traceback" not in page.evaluate("() => document.body.innerText")
        n = len(tab.events)
        box = page.locator(f'[id="{tab.sl_thr._impl.uuid}"]').locator("xpath=../..") \
            .locator("input.mantine-NumberInput-input")
        box.fill("0.3")
        box.press("Enter")
        wait_for(lambda: any(e[0] == "settings" and abs(e[1].threshold - 0.3) < 1e-9 for e in tab.events[n:]),
                 what="the tab's threshold")
        assert tab.fast.wait_idle(60)
        page2, _ = open_tab(browser, app)                # a new tab opens and is told too
        shown_text(page2, re.compile(r"^Cannot compute the paper preset")).wait_for(timeout=60_000)
        assert http_status(app.server.get_port(), b"/")[0] == 200
        page.context.close()
        page2.context.close()
    finally:
        app.close()
    assert os.environ.get("CROWDCAM_FAULT") == f"kill:{i},{j}"      # (monkeypatch restores it)
