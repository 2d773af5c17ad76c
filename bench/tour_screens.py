"""Screenshots of every tour step, and the server-side time from a step change to its picture.

    .venv/bin/python bench/tour_screens.py SET --out DIR [--size 1920x1080 --size 1366x768]
                                           [--presenter] [--max-side 640]

Runs the inspector in this process (the per-pair cache makes a computed set start at once),
opens it in Debian's Chromium, waits for the whole run, starts the tour and turns the pages
with the arrow key, waiting for each step's picture to be sent (the session's "tour shown"
event) and for the tab to settle before each screenshot. Writes DIR/<set>_<W>x<H>_step<k>.png
(and .jpg) and prints the step latencies (ms, server-side: "next" to the picture sent; for step 1
with cameras, to the Geometry view drawn). `crowdcam bench --ui SET` times the steps without a
browser, over several walks.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

CHROMIUM = "/usr/bin/chromium"
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
        "--disable-background-networking", "--disable-component-update", "--disable-sync",
        "--use-angle=swiftshader", "--enable-unsafe-swiftshader"]


def wait_for(pred, timeout=600.0, what="condition"):
    t0 = time.time()
    while time.time() - t0 < timeout:
        if pred():
            return
        time.sleep(0.02)
    raise TimeoutError(f"timed out waiting for {what}")


def settled(tab):
    """Every redrawer of the tab idle at once (its gallery and preset panels too, which a tab
    computes once its pairs are in: the timings are those of a settled tab, as in a class)."""
    draws = (tab.slow, tab.fast, tab.geo_draw, tab.gallery.draw, tab.presets.draw)
    for _ in range(1000):
        for d in draws:
            d.wait_idle(600)
        if all(d.idle() for d in draws):
            return


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("set")
    ap.add_argument("--out", required=True)
    ap.add_argument("--size", action="append", default=None)
    ap.add_argument("--presenter", action="store_true")
    ap.add_argument("--max-side", type=int, default=640)
    ap.add_argument("--jpeg-quality", type=int, default=80)
    ap.add_argument("--verbose", action="store_true")
    a = ap.parse_args(argv)
    sizes = [tuple(int(v) for v in s.split("x")) for s in (a.size or ["1920x1080", "1366x768"])]
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)

    from PIL import Image
    from playwright.sync_api import sync_playwright

    from inspector.app import Inspector
    from pipeline.cache import PairCache, default_cache_dir
    from pipeline.loading import load_gts, load_set
    ps = load_set(Path(a.set), a.max_side)
    app = Inspector(ps, load_gts(ps), PairCache(default_cache_dir()), out / "inspector-out", port=0,
                    max_side=a.max_side)
    all_ms = []
    try:
        with sync_playwright() as pw:
            b = pw.chromium.launch(executable_path=CHROMIUM, headless=True, args=ARGS)
            for w, h in sizes:
                page = b.new_page(viewport={"width": w, "height": h})
                before = set(app.sessions)
                page.goto(app.url)
                wait_for(lambda: set(app.sessions) - before, what="the session")
                tab = app.sessions[(set(app.sessions) - before).pop()]
                page.get_by_text("Ready:", exact=False).first.wait_for(timeout=1_800_000)
                settled(tab)
                close = page.locator(".mantine-Notification-closeButton")   # "software WebGL" toast
                if close.count():
                    close.first.click()
                page.get_by_role("button", name="Take the guided tour").click()
                for k in range(1, 8):
                    if k > 1:
                        n = len(tab.events)
                        page.evaluate("document.activeElement && document.activeElement.blur()")
                        page.keyboard.press("ArrowRight")       # nothing has the focus: the page turns
                        wait_for(lambda: ("tour shown", k) in tab.events[n:], what=f"step {k}")
                    else:
                        wait_for(lambda: ("tour shown", 1) in tab.events, what="step 1")
                    if k == 1 and a.presenter:      # as the checkbox does (a click would scroll the panel to it)
                        tab.tour.set_presenter(True)
                        wait_for(lambda: ("presenter", True) in tab.events, what="presenter")
                    settled(tab)
                    if a.verbose:
                        print(k, tab.events[-12:], tab.report is not None and tab.report.xy, tab.pixel, flush=True)
                    page.wait_for_timeout(400)          # the browser decodes the last picture
                    png = out / f"{ps.name}_{w}x{h}_step{k}.png"
                    page.screenshot(path=str(png))
                    Image.open(png).convert("RGB").save(png.with_suffix(".jpg"), quality=a.jpeg_quality,
                                                        optimize=True)
                print(f"{w}x{h}: step ms {[round(x, 1) for x in tab.tour.step_ms]}")
                all_ms += tab.tour.step_ms
                page.close()
            b.close()
    finally:
        app.close()
    import numpy as np
    ms = np.array(all_ms)
    print(f"step latency (server-side, ms): median {np.median(ms):.1f}, 95th {np.percentile(ms, 95):.1f}, "
          f"max {ms.max():.1f} over {len(ms)} steps")
    return 0


if __name__ == "__main__":
    sys.exit(main())
