"""A screenshot of the inspector's Gallery tab with an entry opened, and the gallery's build time.

    .venv/bin/python bench/gallery_screens.py SET --out DIR [--size 1280x720] [--max-side 640] [--entry 1]

Runs the inspector in this process (the per-pair cache makes a computed set start at once),
opens it in Debian's Chromium, waits for the whole run and for the shown reference's gallery,
opens the Gallery tab, clicks entry k and waits for its pixel to be explained (the session's
"explained" event) and the tab to settle. Writes DIR/<set>_gallery_<W>x<H>.png (and .jpg) and
prints the gallery's server-side build time (build_gallery plus the crops).
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


def wait_for(pred, timeout=1800.0, what="condition"):
    t0 = time.time()
    while time.time() - t0 < timeout:
        if pred():
            return
        time.sleep(0.02)
    raise TimeoutError(f"timed out waiting for {what}")


def settled(tab):
    for _ in range(1000):
        tab.slow.wait_idle(300)
        tab.fast.wait_idle(120)
        tab.gallery.draw.wait_idle(600)
        if tab.slow.idle() and tab.fast.idle() and tab.gallery.draw.idle():
            return


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("set")
    ap.add_argument("--out", required=True)
    ap.add_argument("--size", action="append", default=None)
    ap.add_argument("--max-side", type=int, default=640)
    ap.add_argument("--entry", type=int, default=1, help="the entry to open, 1 = the first")
    ap.add_argument("--jpeg-quality", type=int, default=80)
    a = ap.parse_args(argv)
    sizes = [tuple(int(v) for v in s.split("x")) for s in (a.size or ["1280x720"])]
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    from PIL import Image
    from playwright.sync_api import sync_playwright

    from inspector.app import Inspector
    from inspector.gallery_view import entry_label
    from pipeline.cache import PairCache, default_cache_dir
    from pipeline.loading import load_gts, load_set
    ps = load_set(Path(a.set), a.max_side)
    app = Inspector(ps, load_gts(ps), PairCache(default_cache_dir()), out / "inspector-out", port=0,
                    max_side=a.max_side)
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
                g = tab.gallery
                wait_for(lambda: g.gallery is not None and g.key == g.state(), what="the gallery")
                settled(tab)
                close = page.locator(".mantine-Notification-closeButton")   # "software WebGL" toast
                if close.count():
                    close.first.click()
                page.get_by_role("tab", name="Gallery").click()
                entries = g.gallery.entries
                if entries:
                    e = entries[min(a.entry, len(entries)) - 1]
                    n = len(tab.events)
                    page.get_by_role("button", name=entry_label(e)).click()
                    wait_for(lambda: any(ev[0] == "explained" for ev in tab.events[n:]), what="the explanation")
                    settled(tab)
                page.wait_for_timeout(400)          # the browser decodes the last picture
                png = out / f"{ps.name}_gallery_{w}x{h}.png"
                page.screenshot(path=str(png))
                Image.open(png).convert("RGB").save(png.with_suffix(".jpg"), quality=a.jpeg_quality, optimize=True)
                print(f"{w}x{h}: {png}; gallery build ms {[round(x, 1) for x in g.compute_ms]}")
                page.close()
            b.close()
    finally:
        app.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
