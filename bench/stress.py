"""Load and faults, measured: `make stress` (or `python -m bench.stress`). A maintainer reruns it
after a change to the inspector or the runner; it prints one table, and exits 1 if a check fails.

1. Ten tabs (Playwright, Debian's Chromium) on one inspector that runs in this process, each
   typing its own thresholds and picking its own references for a minute, all at once. After
   every round each tab must show its own state: the Evaluation text "<reference>: Jaccard at <its
   threshold>" on the server and in the page, nothing else. Measured: the server-side main-view
   redraws (Session.main_ms: compose, overlay, JPEG encode and send), this process's RSS before,
   during and after, the sessions before and after the tabs close.
2. Requests for paths outside the page's own assets (traversal, encoded traversal, absolute
   paths, the set's own files), sent raw over a socket so nothing normalises them: all 404.
3. Faults of `crowdcam detect` (injected as tests/test_faults.py does, run._fault_injection):
   a worker killed once (the result must equal a clean run's) and twice (exit 3, one line, a
   re-run resumes); Ctrl-C while a worker is inside a pair (seconds to stop, orphan processes,
   partial output); a corrupted cache entry (healed: warned, rewritten, same maps); a full disk
   while writing the outputs (exit 3, nothing half-written).

The RSS is this Python process's: the viser server, the inspector and Playwright's small client
(Chromium runs in its own processes). The machine may be shared: the figures say what it was
doing (load average) beside them.
"""

from __future__ import annotations

import argparse
import errno
import gc
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import weakref
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
SAMPLE_SETS = ROOT / "sample_sets"
CHROMIUM = "/usr/bin/chromium"
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
        "--disable-background-networking", "--disable-component-update", "--disable-sync",
        "--use-angle=swiftshader", "--enable-unsafe-swiftshader"]


# ----------------------------------------------------------------------------- raw HTTP probes
def http_status(port: int, target: bytes, host: str = "127.0.0.1", timeout: float = 10.0) -> tuple[int | None, bytes]:
    """Send `GET <target> HTTP/1.1` as raw bytes (no client normalises the path); (status or
    None if the server closed without one, body)."""
    with socket.create_connection((host, port), timeout=timeout) as c:
        c.sendall(b"GET " + target + b" HTTP/1.1\r\nHost: " + host.encode() + b"\r\nConnection: close\r\n\r\n")
        data = b""
        while True:
            try:
                d = c.recv(65536)
            except socket.timeout:
                break
            if not d:
                break
            data += d
    head, _, body = data.partition(b"\r\n\r\n")
    m = re.match(rb"HTTP/1\.[01] (\d{3})", head)
    return (int(m.group(1)) if m else None), body


OWN_PAGE = [b"/", b"/index.html", b"/?x=../../etc/passwd"]


def outside_paths(set_dir: Path, also: list[Path] = ()) -> list[bytes]:
    """Request targets that name something other than the page: traversal, encoded traversal,
    absolute paths, viser's own sources beside its page, and the files of the set folder (by
    name, by path relative to the repository and by absolute path), plus `also` (the cache,
    the output folder ...)."""
    from urllib.parse import quote
    targets = [b"/../", b"/..", b"/../../../../../../etc/passwd", b"/./../etc/passwd", b"/index.html/../../x",
               b"/%2e%2e/%2e%2e/%2e%2e/etc/passwd", b"/%2E%2E%2F%2E%2E%2F%2E%2E%2Fetc%2Fpasswd",
               b"/..%2f..%2f..%2fetc%2fpasswd", b"/..%5c..%5c..%5cetc%5cpasswd", b"/..\\..\\..\\etc\\passwd",
               b"/%252e%252e/%252e%252e/etc/passwd", b"/%c0%ae%c0%ae/%c0%ae%c0%ae/etc/passwd",
               b"/etc/passwd", b"//etc/passwd", b"/%2Fetc%2Fpasswd", b"/proc/self/environ", b"/proc/self/cmdline",
               b"/index.html%00.jpg", b"/%00", b"/../_viser.py", b"/../../_viser.py", b"/../../__init__.py",
               b"/%2e%2e/%2e%2e/_viser.py", b"/client/build/index.html",
               b"http://127.0.0.1/../../etc/passwd", b"../../etc/passwd", b"*"]
    files = sorted(p for p in Path(set_dir).rglob("*") if p.is_file())[:6]
    for p in list(files) + [Path(a) for a in also]:
        p = Path(p).resolve()
        rel = [p.name, str(p.relative_to(set_dir.resolve())) if p.is_relative_to(set_dir.resolve()) else p.name]
        if p.is_relative_to(ROOT):
            rel.append(str(p.relative_to(ROOT)))
        for r in rel:
            targets += [b"/" + quote(r).encode(), b"/../" + quote(r).encode()]
        targets += [quote(str(p)).encode(), b"/" + quote(str(p)).encode(), b"/" + quote(str(p), safe="").encode(),
                    b"/" + b"../" * 12 + quote(str(p).lstrip("/")).encode()]
    return list(dict.fromkeys(targets))


def probe(port: int, set_dir: Path, also: list[Path] = ()) -> dict:
    """Every outside path must be 404; the page itself 200."""
    bad, n = [], 0
    for t in outside_paths(set_dir, also):
        status, _ = http_status(port, t)
        n += 1
        if status != 404:
            bad.append((t.decode(errors="replace"), status))
    own = {t.decode(): http_status(port, t)[0] for t in OWN_PAGE}
    return {"probes": n, "not_404": bad, "own_page": own}


# ----------------------------------------------------------------------------- ten tabs
class _Timed(list):
    """Session.main_ms, which the session replaces by `(main_ms + [ms])[-50:]` after every
    redraw: every value added also goes to `sink`, so none is lost to the cap."""

    def __init__(self, sink: list, items=()):
        super().__init__(items)
        self.sink = sink

    def __add__(self, other):
        self.sink.extend(other)
        return _Timed(self.sink, list.__add__(self, other))

    def __getitem__(self, k):
        r = list.__getitem__(self, k)
        return _Timed(self.sink, r) if isinstance(k, slice) else r


def _wait(pred, timeout: float, what: str) -> None:
    t0 = time.time()
    while not pred():
        if time.time() - t0 > timeout:
            raise TimeoutError(f"timed out waiting for {what}")
        time.sleep(0.02)


def _settled(session, timeout: float = 120.0) -> None:
    """Both redrawers idle at once (a slow draw may ask the fast one to draw, not the reverse)."""
    t0 = time.time()
    while time.time() - t0 < timeout:
        if session.slow.wait_idle(timeout) and session.fast.wait_idle(timeout) and \
                session.slow.idle() and session.fast.idle():
            return
    raise TimeoutError("a tab never settled")


def _rss() -> int:
    import psutil
    return psutil.Process().memory_info().rss


def _jaccard_re(stems: list[str]) -> re.Pattern:
    """"<stem>: Jaccard at <t>", the Evaluation folder's first line (the page's textContent runs
    the words of neighbouring elements together, so the stem is one of the set's)."""
    names = "|".join(re.escape(s) for s in sorted(stems, key=len, reverse=True))
    return re.compile(rf"({names}): Jaccard at (\d\.\d{{3}})")


def _page_jaccards(page, pattern: re.Pattern) -> list[tuple[str, str]]:
    """Every "<stem>: Jaccard at <t>" the page holds (hidden folders included)."""
    return pattern.findall(page.evaluate("() => document.body.textContent"))


def ten_tabs(app, n_tabs: int = 10, seconds: float = 60.0, seed: int = 0, log=print, verbose: bool = False) -> dict:
    """_ten_tabs, then what the closed tabs left: their sessions and threads, and the RSS. (Out
    here, where no frame of the load holds a tab: Playwright's sync API takes snapshots of the
    caller's locals, which would keep the last ones alive.)"""
    out = _ten_tabs(app, n_tabs, seconds, seed, log, verbose=verbose)
    gone = out.pop("_gone")
    gc.collect()
    threads = [t.name for t in threading.enumerate() if re.match(r"tab\d+-(fast|slow)$", t.name)]
    out.update(sessions_after_close=len(app.sessions), tab_threads_after_close=len(threads),
               sessions_in_memory=sum(r() is not None for r in gone), rss_after_close=_rss())
    return out


def _ten_tabs(app, n_tabs: int = 10, seconds: float = 60.0, seed: int = 0, log=print, moves: int = 2,
              verbose: bool = False) -> dict:
    """n_tabs tabs at once, each with its own thresholds and references, for `seconds`; see the
    module docstring. The inspector's run must be done."""
    from playwright.sync_api import sync_playwright
    rng = np.random.default_rng(seed)
    stems = app.stems
    snap = app.models[app.default_preset].snapshot()
    refs = [i for i, s in enumerate(snap.supports) if s and stems[i] in app.gts]
    grid = np.round(np.arange(0.1, 0.9001, 0.005), 3)
    jaccard = _jaccard_re(stems)
    gc.collect()
    out = {"tabs": n_tabs, "seconds": seconds, "rss_before": _rss(), "sessions_before": len(app.sessions)}
    ms: list[float] = []
    rss_log: list[tuple[float, int]] = []
    checks = crossed = rounds = 0
    crossings: list[str] = []
    stop = threading.Event()

    def sample():
        while not stop.wait(1.0):
            rss_log.append((time.time(), _rss()))
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, headless=True, args=ARGS)
        tabs = []
        t_open = time.time()
        for k in range(n_tabs):
            ctx = browser.new_context(viewport={"width": 1280, "height": 720})
            ctx.set_default_timeout(120_000)
            page = ctx.new_page()
            before = set(app.sessions)
            page.goto(app.url)
            page.get_by_text("Threshold", exact=True).first.wait_for(timeout=120_000)
            _wait(lambda: set(app.sessions) - before, 60, "the tab's session")
            session = app.sessions[(set(app.sessions) - before).pop()]
            session.main_ms = _Timed(ms)
            tabs.append((ctx, page, session))
        log(f"  {n_tabs} tabs opened in {time.time() - t_open:.0f} s")
        for _, page, session in tabs:
            page.get_by_text(re.compile(r"^Ready: \d+ pairs")).wait_for(timeout=120_000)
            _settled(session)
        log(f"  {n_tabs} tabs open; moving thresholds and references for {seconds:.0f} s")
        ms.clear()
        gc.collect()
        out["rss_tabs_open"] = _rss()
        sampler = threading.Thread(target=sample, daemon=True)
        sampler.start()
        t_end = time.time() + seconds
        while time.time() < t_end:
            rounds += 1
            # per tab a drag: `moves` values typed in a row, the last one (no two tabs alike) counts
            last = rng.choice(grid, size=n_tabs, replace=False)
            want = []
            t_round = time.time()
            for (_, page, session), t in zip(tabs, last):
                ref = session.settings.ref
                if rng.random() < 0.3:                                  # and now and then another photo
                    ref = int(rng.choice([r for r in refs if r != ref]))
                    page.get_by_role("combobox", name="Reference").click()
                    page.get_by_role("option", name=stems[ref], exact=True).click()
                box = page.locator(f'[id="{session.sl_thr._impl.uuid}"]').locator("xpath=../..") \
                    .locator("input.mantine-NumberInput-input")
                n = len(session.events)
                for v in list(rng.choice(grid[grid != t], size=moves - 1)) + [t]:    # the last one changes it
                    box.fill(f"{v:g}")
                    box.press("Enter")
                want.append((ref, float(t), n))
            t_issued = time.time()
            for (_, page, session), (ref, t, n) in zip(tabs, want):
                # the callback records its event after asking for the redraws: then wait for the main view
                _wait(lambda: any(e[0] == "settings" and e[1].ref == ref and abs(e[1].threshold - t) < 1e-9
                                  for e in session.events[n:]), 120, "the tab's new state on the server")
                _wait(session.fast.idle, 120, "the tab's main view")   # (its slow views may go on drawing)
                own = (stems[ref], f"{t:.3f}")
                checks += 1
                server = jaccard.findall(session.md_eval.content)
                try:                                   # the page shows what the server sent, soon
                    _wait(lambda: _page_jaccards(page, jaccard) == [own], 30, "the page's own state")
                    shown = [own]
                except TimeoutError:
                    shown = _page_jaccards(page, jaccard)
                if server != [own] or shown != [own]:
                    crossed += 1
                    crossings.append(f"tab {session.client.client_id}: wants {own}, server {server}, page {shown}")
            if verbose:
                log(f"  round {rounds}: issued in {t_issued - t_round:.1f} s, checked in {time.time() - t_issued:.1f} s")
        stop.set()
        sampler.join()
        gc.collect()
        out["rss_after"] = _rss()
        out["sessions_open"] = len(app.sessions)
        t0 = time.time()
        for ctx, _, _ in tabs:
            ctx.close()
        try:
            _wait(lambda: not app.sessions, 60, "the sessions to be freed")
        except TimeoutError:
            pass
        out["close_s"] = time.time() - t0
        browser.close()
    out.update(_gone=[weakref.ref(s) for _, _, s in tabs], redraws=len(ms), rounds=rounds, checks=checks,
               crossed=crossed, crossings=crossings[:5])
    arr = np.array(ms) if ms else np.array([np.nan])
    out.update(redraw_median_ms=float(np.median(arr)), redraw_p95_ms=float(np.percentile(arr, 95)),
               redraw_max_ms=float(arr.max()))
    if rss_log:
        r = np.array([v for _, v in rss_log])
        out.update(rss_min=int(r.min()), rss_max=int(r.max()), rss_first=int(r[0]), rss_last=int(r[-1]))
    return out


# ----------------------------------------------------------------------------- faults of `crowdcam detect`
FAULT_SET = SAMPLE_SETS / "tabletop_ball"


def _detect(out: Path, cache: Path, env_extra: dict | None = None, quiet: bool = True,
            max_side: int = 160) -> subprocess.Popen:
    env = dict(os.environ, **(env_extra or {}))
    cmd = [sys.executable, "-m", "crowdcam", "detect", str(FAULT_SET), "--out", str(out), "--max-side", str(max_side),
           "--preset", "paper", "--workers", "2", "--cache-dir", str(cache)] + (["--quiet"] if quiet else [])
    return subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _maps(out: Path) -> dict[str, np.ndarray]:
    return {p.stem: np.load(p) for p in sorted((out / "maps").glob("*.npy"))}


def _same_maps(a: Path, b: Path) -> bool:
    ma, mb = _maps(a), _maps(b)
    return bool(ma) and ma.keys() == mb.keys() and all(np.array_equal(ma[k], mb[k]) for k in ma)


def _without_pairs(src: Path, dst: Path) -> Path:
    """A copy of a cache with its features and geometry but no pair: a run on it computes only
    pairs (in the worker pool, where the faults are injected), which saves a minute per run."""
    shutil.copytree(src, dst, ignore=shutil.ignore_patterns("pair"))
    return dst


def _alive(pids: list[int]) -> list[int]:
    import psutil
    alive = []
    for pid in pids:
        try:
            if psutil.Process(pid).status() != psutil.STATUS_ZOMBIE:
                alive.append(pid)
        except psutil.NoSuchProcess:
            pass
    return alive


def faults(tmp: Path, log=print, max_side: int = 160) -> dict:
    import psutil
    res: dict = {}
    # a clean run: the reference maps, and the pair order (the reference with most supports first)
    t0 = time.time()
    p = _detect(tmp / "clean", tmp / "cache-clean", max_side=max_side)
    code = p.wait(timeout=1200)
    assert code == 0, p.stderr.read()
    res["clean_s"] = time.time() - t0
    summ = json.loads((tmp / "clean" / "summary.json").read_text())
    stems = [im["stem"] for im in summ["images"]]
    sups = [[stems.index(s) for s in im["supports"]] for im in summ["images"]]
    first = max(range(len(sups)), key=lambda i: (len(sups[i]), -i))
    order = sorted(((i, j) for i, s in enumerate(sups) for j in s), key=lambda ij: ij[0] != first)
    log(f"  clean run: {res['clean_s']:.1f} s, {len(order)} pairs")

    # a worker killed once: replaced, the pair retried, the same maps
    i, j = order[0]
    p = _detect(tmp / "kill1", _without_pairs(tmp / "cache-clean", tmp / "cache-kill1"),
                {"CROWDCAM_FAULT": f"kill:{i},{j}", "CROWDCAM_FAULT_ONCE": str(tmp / "killed")}, max_side=max_side)
    code = p.wait(timeout=1200)
    res["kill_once"] = {"exit": code, "killed": (tmp / "killed").exists(),
                        "same_maps": code == 0 and _same_maps(tmp / "kill1", tmp / "clean")}
    # killed every time: one line, exit 3, the finished pairs cached; a re-run resumes
    i, j = order[-1]
    cache2 = _without_pairs(tmp / "cache-clean", tmp / "cache-kill2")
    p = _detect(tmp / "kill2", cache2, {"CROWDCAM_FAULT": f"kill:{i},{j}"}, max_side=max_side)
    code = p.wait(timeout=1200)
    err = p.stderr.read()
    cached = len(list((cache2 / "pair").rglob("*.npz")))
    t0 = time.time()
    p = _detect(tmp / "kill2", cache2, max_side=max_side)
    code2 = p.wait(timeout=1200)
    res["kill_twice"] = {"exit": code, "lines": err.count("\n"), "traceback": "Traceback" in err,
                         "message": err.strip()[:160], "pairs_cached": cached, "of": len(order),
                         "resume_exit": code2, "resume_s": time.time() - t0,
                         "same_maps": code2 == 0 and _same_maps(tmp / "kill2", tmp / "clean")}
    log(f"  killed workers: once -> exit {res['kill_once']['exit']}, twice -> exit {code}")

    # Ctrl-C while a worker is inside a pair
    i, j = order[0]
    marker = tmp / "hanging"
    p = _detect(tmp / "ctrlc", _without_pairs(tmp / "cache-clean", tmp / "cache-ctrlc"),
                {"CROWDCAM_FAULT": f"hang:{i},{j}", "CROWDCAM_FAULT_ONCE": str(marker)}, max_side=max_side)
    _wait(lambda: marker.exists() or p.poll() is not None, 1200, "a worker inside the pair")
    children = [c.pid for c in psutil.Process(p.pid).children(recursive=True)]
    t0 = time.time()
    p.send_signal(signal.SIGINT)
    code = p.wait(timeout=60)
    stop_s = time.time() - t0
    orphans_at_exit = _alive(children)
    time.sleep(1.0)
    res["ctrl_c"] = {"exit": code, "stop_s": stop_s, "children": len(children),
                     "orphans_at_exit": len(orphans_at_exit), "orphans_after_1s": len(_alive(children)),
                     "traceback": "Traceback" in p.stderr.read(),
                     "partial_output": (tmp / "ctrlc").exists() or bool(list(tmp.glob(".ctrlc.partial-*")))}
    for pid in _alive(children):          # never leave one behind, even when the check fails
        os.kill(pid, signal.SIGKILL)
    log(f"  Ctrl-C: stopped in {stop_s:.2f} s")

    # a corrupted cache: one geometry entry emptied (as a crash leaves it), one photo's cached map
    # flipped (a re-run reads the maps, not the pairs: a bad pair is found and recomputed when a
    # viewer reads it, tests/test_cache.py)
    cache = tmp / "cache-clean"
    geo = sorted((cache / "geometry").rglob("*.npz"))[0]
    pair = sorted((cache / "dynamic").rglob("*.npz"))[0]
    geo.write_bytes(b"")
    raw = bytearray(pair.read_bytes())
    raw[len(raw) // 2] ^= 0xFF
    pair.write_bytes(bytes(raw))
    p = _detect(tmp / "healed", cache, quiet=False, max_side=max_side)
    code = p.wait(timeout=1200)
    err = p.stderr.read()
    from pipeline.cache import unpack

    def valid(f: Path) -> bool:
        try:
            unpack(f.read_bytes())
            return True
        except (OSError, ValueError):
            return False
    res["corrupt_cache"] = {"exit": code, "warnings": err.count("bad cache entry"), "traceback": "Traceback" in err,
                            "rewritten_valid": valid(geo) and valid(pair),
                            "same_maps": code == 0 and _same_maps(tmp / "healed", tmp / "clean")}

    # a full disk while the outputs are written (as tests/test_faults.py): the third image write fails
    from crowdcam import cli
    from pipeline import output
    real, calls = output._imwrite, [0]

    def full(path, img, params=None):
        calls[0] += 1
        if calls[0] > 2:
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        real(path, img, params)
    output._imwrite = full
    try:
        import contextlib
        import io
        err = io.StringIO()
        with contextlib.redirect_stderr(err):
            code = cli.main(["detect", str(FAULT_SET), "--out", str(tmp / "full"), "--max-side", str(max_side),
                             "--preset", "paper", "--workers", "1", "--quiet", "--cache-dir", str(tmp / "cache-clean")])
    finally:
        output._imwrite = real
    left = [q.name for q in tmp.iterdir() if q.name.startswith((".full", "full"))]
    res["full_disk"] = {"exit": code, "lines": err.getvalue().count("\n"), "left": left,
                        "message": err.getvalue().strip()[:160]}
    return res


# ----------------------------------------------------------------------------- the inspector under attack
def failing_run(tmp: Path, cache: Path, max_side: int) -> dict:
    """An inspector whose run ends in an error (workers killed twice on a pair): does the page
    say so, and does the server go on serving?"""
    from playwright.sync_api import sync_playwright

    from inspector.app import Inspector
    from pipeline.cache import PairCache
    from pipeline.loading import load_gts, load_set
    ps = load_set(FAULT_SET, max_side)
    cache = _without_pairs(cache, tmp / "cache-failing")
    hold = threading.Event()                       # the pair order first (geometry from the cache)
    a = Inspector(ps, load_gts(ps), PairCache(cache), tmp / "out-failing", port=0, preset="paper",
                  max_side=max_side, workers=1, hold=hold)
    m = a.models["paper"]
    _wait(lambda: m.supports is not None, 600, "the support sets")
    i, j = m.first_ref, m.supports[m.first_ref][0]
    a.close()
    old = os.environ.get("CROWDCAM_FAULT")
    os.environ["CROWDCAM_FAULT"] = f"kill:{i},{j}"
    try:
        a = Inspector(ps, load_gts(ps), PairCache(cache), tmp / "out-failing", port=0, preset="paper",
                      max_side=max_side, workers=2)
        m = a.models["paper"]
        _wait(lambda: m.status in ("done", "failed"), 600, "the run's end")
    finally:
        if old is None:
            os.environ.pop("CROWDCAM_FAULT", None)
        else:
            os.environ["CROWDCAM_FAULT"] = old
    res = {"status": m.status, "error": m.error}
    try:
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, headless=True, args=ARGS)
            page = browser.new_page()
            page.goto(a.url)
            try:
                page.get_by_text(re.compile("^Cannot compute the paper preset")).wait_for(timeout=60_000)
                res["page_says"] = True
            except Exception:
                res["page_says"] = False
            browser.close()
        res["server_alive"] = http_status(a.server.get_port(), b"/")[0] == 200
    finally:
        a.close()
    return res


# ----------------------------------------------------------------------------- main
def _mb(b: int) -> str:
    return f"{b / 2**20:.0f} MB"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--set", default=str(FAULT_SET), help="the set the tabs look at (default tabletop_ball)")
    ap.add_argument("--max-side", type=int, default=256, help="the tabs' working resolution (default 256)")
    ap.add_argument("--tabs", type=int, default=10)
    ap.add_argument("--seconds", type=float, default=60.0, help="how long the tabs move (default 60)")
    ap.add_argument("--cache-dir", default=str(ROOT / "crowdcam-out" / "stress" / "cache"),
                    help="the tabs' cache, kept between runs (default crowdcam-out/stress/cache)")
    ap.add_argument("--skip-tabs", action="store_true")
    ap.add_argument("--skip-faults", action="store_true")
    ap.add_argument("--verbose", action="store_true", help="say how long each round of the tabs took")
    args = ap.parse_args(argv)
    os.environ.setdefault("CROWDCAM_CACHE", str(Path(args.cache_dir)))     # nothing in the user's cache

    from inspector.app import Inspector
    from pipeline.cache import PairCache
    from pipeline.loading import load_gts, load_set

    def log(msg: str) -> None:
        print(msg, file=sys.stderr, flush=True)
    load0 = os.getloadavg()
    t_all = time.time()
    tmp = Path(tempfile.mkdtemp(prefix="crowdcam-stress-"))
    rows: list[tuple[str, str, bool]] = []       # (check, figure, ok)
    try:
        set_dir = Path(args.set)
        ps = load_set(set_dir, args.max_side)
        t0 = time.time()
        app = Inspector(ps, load_gts(ps), PairCache(Path(args.cache_dir)), tmp / "out", port=0,
                        max_side=args.max_side)
        model = app.models[app.default_preset]
        _wait(lambda: model.status in ("done", "failed"), 1800, "the inspector's run")
        log(f"inspector on {ps.name} at {args.max_side} px: {model.status} in {time.time() - t0:.1f} s ({app.url})")
        try:
            pr = probe(app.server.get_port(), set_dir, [Path(args.cache_dir), tmp / "out", ROOT / "README.md"])
            rows.append(("paths outside the page -> 404", f"{pr['probes'] - len(pr['not_404'])} of {pr['probes']}"
                         + (f"; not 404: {pr['not_404'][:3]}" if pr["not_404"] else ""), not pr["not_404"]))
            rows.append(("the page itself -> 200", ", ".join(f"{k} {v}" for k, v in pr["own_page"].items()),
                         all(v == 200 for v in pr["own_page"].values())))
            if not args.skip_tabs:
                r = ten_tabs(app, args.tabs, args.seconds, log=log, verbose=args.verbose)
                rows += [
                    (f"{r['tabs']} tabs, {r['seconds']:.0f} s: rounds / state checks", f"{r['rounds']} / {r['checks']}",
                     r["checks"] > 0),
                    ("crossed or wrong state (must be 0)", f"{r['crossed']}" + (f": {r['crossings']}" if r["crossed"]
                                                                                else ""), r["crossed"] == 0),
                    ("main-view redraws: n, median / p95 / max",
                     f"{r['redraws']}, {r['redraw_median_ms']:.1f} / {r['redraw_p95_ms']:.1f} / "
                     f"{r['redraw_max_ms']:.1f} ms", r["redraw_median_ms"] <= 150),
                    ("server RSS: no tab / tabs open / after the minute / tabs closed",
                     f"{_mb(r['rss_before'])} / {_mb(r['rss_tabs_open'])} / {_mb(r['rss_after'])} / "
                     f"{_mb(r['rss_after_close'])}", r["rss_after"] < r["rss_tabs_open"] + 100 * 2**20),
                    ("server RSS during the minute: first / last / min / max",
                     f"{_mb(r.get('rss_first', 0))} / {_mb(r.get('rss_last', 0))} / {_mb(r.get('rss_min', 0))} / "
                     f"{_mb(r.get('rss_max', 0))}", r.get("rss_last", 0) < r.get("rss_first", 0) + 100 * 2**20),
                    ("sessions: tabs open / closed (threads, objects left)",
                     f"{r['sessions_open']} / {r['sessions_after_close']} ({r['tab_threads_after_close']}, "
                     f"{r['sessions_in_memory']}), freed in {r['close_s']:.1f} s",
                     r["sessions_after_close"] == 0 and r["tab_threads_after_close"] == 0
                     and r["sessions_in_memory"] == 0)]
        finally:
            app.close()
        if not args.skip_faults:
            log("faults of `crowdcam detect` (tabletop_ball, paper preset, 160 px, 2 workers)")
            f = faults(tmp, log=log)
            k1, k2, cc, ch, fd = f["kill_once"], f["kill_twice"], f["ctrl_c"], f["corrupt_cache"], f["full_disk"]
            rows += [
                ("worker killed once -> exit, same maps as a clean run", f"{k1['exit']}, {k1['same_maps']}",
                 k1["exit"] == 0 and k1["killed"] and k1["same_maps"]),
                ("worker killed twice -> exit, lines, traceback", f"{k2['exit']}, {k2['lines']}, {k2['traceback']}",
                 k2["exit"] == 3 and k2["lines"] == 1 and not k2["traceback"]),
                ("  ... pairs cached; re-run: exit, same maps",
                 f"{k2['pairs_cached']} of {k2['of']}; {k2['resume_exit']}, {k2['same_maps']}",
                 k2["pairs_cached"] > 0 and k2["resume_exit"] == 0 and k2["same_maps"]),
                ("Ctrl-C in a pair -> s to stop (<= 2), exit",
                 f"{cc['stop_s']:.2f} s, {cc['exit']}", cc["stop_s"] <= 2.0 and cc["exit"] == 130),
                ("  ... orphans of its processes: at exit / 1 s later; partial output",
                 f"{cc['orphans_at_exit']} / {cc['orphans_after_1s']} of {cc['children']}; {cc['partial_output']}",
                 cc["orphans_after_1s"] == 0 and not cc["partial_output"] and not cc["traceback"]),
                ("corrupted cache (1 emptied, 1 flipped) -> warnings, healed, same maps",
                 f"{ch['warnings']}, {ch['rewritten_valid']}, {ch['same_maps']}",
                 ch["exit"] == 0 and ch["warnings"] == 2 and ch["rewritten_valid"] and ch["same_maps"]),
                ("full disk writing outputs -> exit, lines, left behind",
                 f"{fd['exit']}, {fd['lines']}, {fd['left'] or 'nothing'}",
                 fd["exit"] == 3 and fd["lines"] == 1 and not fd["left"]),
            ]
            fr = failing_run(tmp, tmp / "cache-clean", 160)
            rows.append(("inspector run fails (workers killed) -> page says it, server alive",
                         f"{fr['page_says']}, {fr['server_alive']}",
                         fr["status"] == "failed" and fr["page_says"] and fr["server_alive"]))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    load1 = os.getloadavg()
    w, fw = max(len(r[0]) for r in rows), max(len(r[1]) for r in rows)
    print(f"\ncrowdcam stress: {Path(args.set).name} at {args.max_side} px, {time.time() - t_all:.0f} s in all; "
          f"{os.cpu_count()} cores, load average {load0[0]:.1f} at the start, {load1[0]:.1f} at the end")
    print(f"{'check':<{w}}  {'figure':<{fw}}  ok")
    for name, fig, ok in rows:
        print(f"{name:<{w}}  {fig:<{fw}}  {'yes' if ok else 'NO'}")
    return 0 if all(ok for _, _, ok in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
