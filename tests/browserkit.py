"""What the real-browser tests share: Debian's Chromium and how to wait on the inspector's state.

Waits poll a state the server records (an event, a redrawer going idle), never a delay: a test
that waits for a state does not race the machine's load.
"""

from __future__ import annotations

import time
from pathlib import Path

import pytest

CHROMIUM = "/usr/bin/chromium"       # Debian's package (make test installs it); never `playwright install`
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
        "--disable-background-networking", "--disable-component-update", "--disable-sync",
        "--use-angle=swiftshader", "--enable-unsafe-swiftshader"]


def wait_for(pred, timeout=120.0, what="condition"):
    """Poll a condition the server sets (an explicit state, not a delay)."""
    t0 = time.time()
    while time.time() - t0 < timeout:
        if pred():
            return
        time.sleep(0.02)
    raise AssertionError(f"timed out waiting for {what}")


def settled(session):
    """Both redrawers idle at once. A slow draw may ask the fast one to draw (never the other
    way), so: slow idle, then fast idle, then slow still idle."""
    for _ in range(1000):
        assert session.slow.wait_idle(120) and session.fast.wait_idle(60)
        if session.slow.idle() and session.fast.idle():
            return
    raise AssertionError("the tab never settled")


def wait_event(session, name, pred=lambda v: True, after=0, timeout=120.0):
    """Wait until the session records event `name` (with a value satisfying pred) at index >= after;
    callbacks record their event after asking for their redraws."""
    def found():
        return any(e[0] == name and pred(e[1]) for e in session.events[after:])
    wait_for(found, timeout, f"event {name!r}")


NOT_IN_TOOLTIP = "xpath=//*[not(ancestor-or-self::*[@role='tooltip'])]"


def shown_text(page, text, exact: bool | None = None):
    """page.get_by_text, but not inside a hint's tooltip: a hint under the mouse repeats words of the
    panel (the Main view's hint names "Click the reference's picture"), and a strict locator that
    also matched the tooltip failed whenever the mouse happened to rest on that control."""
    return page.get_by_text(text, exact=exact).and_(page.locator(NOT_IN_TOOLTIP))


@pytest.fixture(scope="module")
def browser():
    """One headless Chromium per test module."""
    from playwright.sync_api import sync_playwright
    assert Path(CHROMIUM).exists(), "Debian's chromium is needed (make test installs it)"
    with sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=CHROMIUM, headless=True, args=ARGS)
        yield b
        b.close()
