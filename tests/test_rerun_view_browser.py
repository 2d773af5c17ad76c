"""`crowdcam view` in a real browser: Debian's Chromium driven by Playwright, outside hosts blocked.

The viewer must render from loopback alone, and Ctrl-C must stop it with nothing left running.
"""

import re
import signal
import subprocess
import sys
import time
from urllib.parse import urlparse

import pytest

from conftest import ROOT, SAMPLE_SETS

CHROMIUM = "/usr/bin/chromium"
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
        "--disable-background-networking", "--disable-component-update", "--disable-sync",
        "--use-angle=swiftshader", "--enable-unsafe-swiftshader"]


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("view")
    rrd = tmp / "ball.rrd"
    r = subprocess.run([sys.executable, "-m", "crowdcam", "detect", str(SAMPLE_SETS / "tabletop_ball"), "--out",
                        str(tmp / "out"), "--max-side", "240", "--rrd", str(rrd), "--quiet", "--cache-dir",
                        str(tmp / "cache")], capture_output=True, text=True, cwd=ROOT, timeout=600)
    assert r.returncode == 0, r.stderr
    return rrd


def test_view_serves_the_recording_to_a_browser(recording, tmp_path):
    from playwright.sync_api import sync_playwright
    assert __import__("os").path.exists(CHROMIUM), "Debian's chromium is needed (make test installs it)"
    proc = subprocess.Popen([sys.executable, "-m", "crowdcam", "view", str(recording)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        line = proc.stdout.readline()
        m = re.search(r"(http://127\.0\.0\.1:\d+/\S+)", line)
        assert m, line + proc.stderr.read()
        url = m.group(1)
        blocked, console = [], []
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, headless=True, args=ARGS)
            page = browser.new_page(viewport={"width": 1400, "height": 900})

            def route(r):
                if urlparse(r.request.url).hostname in ("127.0.0.1", "localhost"):
                    r.continue_()
                else:
                    blocked.append(r.request.url)
                    r.abort()
            page.route("**/*", route)
            page.on("console", lambda msg: console.append(msg.text))
            page.goto(url)
            page.wait_for_selector("canvas", timeout=120_000)
            deadline = time.time() + 120
            while not any("event handlers installed" in c for c in console) and time.time() < deadline:
                page.wait_for_timeout(250)
            # the viewer draws the recording some time after its handlers are installed (longer on a
            # busy machine): an empty viewer compresses to a small picture, a drawn one does not
            shot = tmp_path / "rerun_view.png"
            deadline = time.time() + 120
            while len(page.screenshot(path=str(shot))) <= 20_000 and time.time() < deadline:
                page.wait_for_timeout(1000)
            browser.close()
        assert any("event handlers installed" in c for c in console)
        assert shot.stat().st_size > 20_000
    finally:
        proc.send_signal(signal.SIGINT)
        rc = proc.wait(timeout=30)
    assert rc == 0
    time.sleep(0.5)
    left = subprocess.run(["pgrep", "-f", f"rerun --serve-web.*{urlparse(url).port}"], capture_output=True, text=True)
    assert left.stdout.strip() == "", "the rerun server outlived `crowdcam view`"
