"""The `crowdcam` command: detect, inspect, view, eval, bench, make-samples.

Errors a user can cause (missing or unreadable input, no usable geometry, bad options) are
reported as one line `crowdcam: error: ...` with exit code 2; warnings go to stderr and the run
goes on. Nothing else parses argv.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import signal
import sys
import threading
import time
from pathlib import Path

from pipeline.params import DEFAULT_MAX_SIDE

SAMPLE_SETS = Path(__file__).resolve().parents[1] / "sample_sets"
def one_line(msg: str) -> str:
    """A message on one printable line, whatever the file names in it: newlines shown as \\n,
    bytes that are not UTF-8 (kept by Python as surrogates) shown as \\xNN."""
    msg = str(msg).replace("\r", "\\r").replace("\n", "\\n")
    return msg.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")


EXIT_USAGE = 2
EXIT_FAULT = 3          # the machine failed the run (a worker died twice, the disk is full)


class CliError(Exception):
    pass


# ----------------------------------------------------------------------------- output helpers
class Reporter:
    """Progress bars and messages on stderr; silent with --quiet (errors still print)."""

    def __init__(self, quiet: bool):
        self.quiet = quiet
        self._bar = None
        self._stage = None

    def progress(self, stage: str, done: int, total: int) -> None:
        if self.quiet or total <= 0:
            return
        from tqdm import tqdm
        if stage != self._stage:
            self.close()
            self._stage = stage
            # initial: what was already done when the stage's first report came (from the cache, at
            # once) counts in no rate; its first item had shown "76260 img/s"
            self._bar = tqdm(total=total, desc=f"{stage:>9}", unit={"features": "img", "screen": "set", "cameras": "step", "maps": "img"}.get(stage, "pair"),
                             file=sys.stderr, leave=False, dynamic_ncols=True, initial=done)
        self._bar.n = done
        self._bar.refresh()
        if done >= total:
            self.close()

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None
            self._stage = None

    def warn(self, msg: str) -> None:
        self.close()
        print(f"crowdcam: warning: {one_line(msg)}", file=sys.stderr)

    def info(self, msg: str) -> None:
        if not self.quiet:
            self.close()
            print(one_line(msg), file=sys.stderr)


def _params(args):
    from pipeline.params import get_preset
    try:
        p = get_preset(args.preset)
    except ValueError as e:
        raise CliError(str(e)) from None
    if getattr(args, "max_side", None):
        if args.max_side < 64 or args.max_side > 4096:
            raise CliError(f"--max-side must be between 64 and 4096 (got {args.max_side})")
        p = p.replace(max_side=args.max_side)
    try:
        return p.with_settings(getattr(args, "param", None) or [])
    except ValueError as e:
        raise CliError(str(e)) from None


def _cache(args, rep=None):
    from pipeline.cache import PairCache, default_cache_dir
    if getattr(args, "no_cache", False):
        return PairCache(None)
    gb = getattr(args, "cache_max_gb", 5.0)
    if gb is not None and gb <= 0:
        raise CliError(f"--cache-max-gb must be positive (got {gb})")
    return PairCache(Path(args.cache_dir) if getattr(args, "cache_dir", None) else default_cache_dir(),
                     max_bytes=None if gb is None else int(gb * 2**30), warn=rep.warn if rep is not None else None)


def _check_max_supports(k: int | None) -> None:
    """`--max-supports` of detect and bench: None (the default cap), 0 (no cap) or a positive K."""
    if k is not None and k < 0:
        raise CliError(f"--max-supports must be 0 (no cap) or more (got {k})")


def _table_row(name: str, score) -> str:
    return (f"{name:<20} {score.n_images:>3} images  Jaccard opt. per image {score.mean_opt_image:.2f} ± "
            f"{score.std_opt_image:.2f}   opt. per set {score.mean_opt_set:.2f} ± {score.std_opt_set:.2f} "
            f"(threshold {score.set_threshold:.3f}); at {score.mask_threshold:g} {score.mean_at_mask:.2f}")


# ----------------------------------------------------------------------------- commands
def cmd_detect(args) -> int:
    from pipeline.loading import is_inside, load_gts, load_set
    from pipeline.output import write_outputs, to_original
    from pipeline.run import detect_set
    from pipeline.evaluate import score_set

    rep = Reporter(args.quiet)
    params = _params(args)
    set_dir = Path(args.set)
    photo_set = load_set(set_dir, params.max_side, warn=rep.warn, gt_dir=Path(args.gt) if args.gt else None)
    params = params.for_working_side(photo_set.working_side)
    out = Path(args.out) if args.out else Path.cwd() / "crowdcam-out" / photo_set.name
    if is_inside(out, set_dir):
        raise CliError(f"{out}: the output folder must not be inside the input folder {set_dir}")
    colmap_dir = Path(args.export_colmap) if args.export_colmap else None
    if colmap_dir is not None and is_inside(colmap_dir, set_dir):
        raise CliError(f"{colmap_dir}: --export-colmap must not be inside the input folder {set_dir}")
    threshold = params.aggregate.threshold if args.threshold is None else args.threshold
    if not 0.0 <= threshold <= 1.0:
        raise CliError(f"--threshold must be in [0, 1] (got {threshold})")
    rep.info(f"{photo_set.name}: {len(photo_set.photos)} photos, preset {params.preset}, "
             f"working size {params.max_side} px")
    t0 = time.perf_counter()
    _check_max_supports(args.max_supports)
    res = detect_set(photo_set, params, _cache(args, rep), workers=args.workers, progress=rep.progress, warn=rep.warn,
                     max_supports=args.max_supports, scheduler=args.scheduler)
    rep.close()
    res.timings["total_s"] = time.perf_counter() - t0
    extra = {}
    gts = load_gts(photo_set)
    probs = {p.stem: to_original(d, p) for p, d in zip(photo_set.photos, res.dynamic)
             if d is not None and p.stem in gts}
    if probs:
        score = score_set(probs, {k: gts[k] for k in probs}, mask_threshold=threshold)
        extra["evaluation"] = score.to_dict()
        rep.info(_table_row(photo_set.name, score))
    live = None
    if args.rrd or args.rerun_web:
        extra["rerun_s"], live = _log_rerun(args, res, photo_set, threshold, gts, rep)
    peaks = []                       # the strongest evidence of each photo whose mask is empty
    for p, d in zip(photo_set.photos, res.dynamic):
        if d is not None and not (d > threshold).any():
            rep.warn(f"{p.path}: no pixel above the threshold {threshold:g} (P_dynamic {float(d.min()):.2f}-"
                     f"{float(d.max()):.2f}); its mask is empty")
            peaks.append(float(d.max()))
    if len(peaks) > 1:
        # once for the set: on real photos the maps understate movers (README: Limitations), and a
        # user who sees only empty masks should know where the maps stand and what to change
        rep.warn(f"{len(peaks)} of {sum(d is not None for d in res.dynamic)} masks are empty at {threshold:g}; "
                 f"their maps peak at {min(peaks):.2f}-{max(peaks):.2f}. If the photos hold movers, a lower "
                 f"--threshold (or the inspector's slider) marks them: on real photos the maps understate movers "
                 f"(README: Limitations)")
    write_outputs(res, out, threshold, extra)
    if colmap_dir is not None:
        _export_colmap(res, colmap_dir, rep)
    n_ok = sum(d is not None for d in res.dynamic)
    n_pairs = len(res.pair_results)
    rep.info(f"wrote {n_ok} maps to {out} ({n_pairs} ordered pairs, "
             f"{res.timings['total_s']:.1f} s, {res.cache_hits} cached)")
    if live is not None:
        _serve_live(live)
    return 0


def _export_colmap(res, target: Path, rep) -> None:
    """The set's reconstruction in COLMAP's text format, put in place complete (staging + rename)."""
    import shutil
    import tempfile

    from pipeline.reconstruction import export_colmap_text
    cams = res.cameras
    if cams is None or not cams.n_registered:
        why = "the preset does not reconstruct the set" if cams is None else cams.reasons[0]
        rep.warn(f"{target}: not written: no reconstruction ({why})")
        return
    target.parent.mkdir(parents=True, exist_ok=True)
    stage = Path(tempfile.mkdtemp(prefix=f".{target.name}.partial-", dir=target.parent))
    try:
        export_colmap_text(cams, res.photo_set.photos, res.keypoints, stage)
        if target.exists():
            shutil.rmtree(target)
        os.replace(stage, target)
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        raise
    rep.info(f"wrote the reconstruction ({cams.n_registered} cameras, {len(cams.points)} points) "
             f"in COLMAP's text format to {target}")


def _parse_pixels(specs: list[str] | None):
    import numpy as np
    if not specs:
        return None
    try:
        return np.array([[float(v) for v in sp.split(",")] for sp in specs], np.float64).reshape(-1, 2)
    except ValueError:
        raise CliError(f"--rr-pixel takes X,Y in working-resolution pixels (got {specs})") from None


def _log_rerun(args, res, photo_set, threshold, gts, rep):
    """Record the run (--rrd FILE, written atomically) and/or stream it live (--rerun-web).

    Returns (seconds spent, live) where live is (viewer, recording stream) to keep serving, or None.
    """
    import os
    import tempfile

    import rerun as rr

    from pipeline.rerun_log import log_run, make_blueprint

    t0 = time.perf_counter()
    stems = [p.stem for p in photo_set.photos]
    focus = None
    if args.rr_ref:
        if args.rr_ref not in stems:
            raise CliError(f"--rr-ref {args.rr_ref}: no photo with that stem in the set")
        focus = stems.index(args.rr_ref)
    rec = rr.RecordingStream("crowdcam", recording_id=f"{photo_set.name}-{int(time.time())}")
    tmp, web, sinks = None, None, []
    try:
        if args.rrd:
            target = Path(args.rrd)
            target.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".partial", dir=target.parent)
            os.close(fd)
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(tmp, 0o666 & ~umask)       # mkstemp makes 0600; the recording is an ordinary file
            sinks.append(rr.FileSink(tmp))
        if args.rerun_web:
            from crowdcam.rerun_web import RerunWeb
            web = RerunWeb()
            sinks.append(rr.GrpcSink(web.grpc_uri))
        rec.set_sinks(*sinks)                   # one stream, written to the file and streamed live
        desc = log_run(res, rec, focus=focus, pixels=_parse_pixels(args.rr_pixel), gts=gts,
                       threshold=threshold)
        rec.send_blueprint(make_blueprint(desc))
        rec.flush()
        if web is not None:                     # the file is finished when the live session ends
            live, tmp = _LiveSession(web, rec, tmp, args.rrd, rep), None
            return time.perf_counter() - t0, live
        if tmp:
            rec.disconnect()                    # closes the file with its footer
            _publish(tmp, args.rrd, rep)
            tmp = None
    except BaseException:
        if web is not None:
            rec.disconnect()
            web.close()
        raise
    finally:
        if tmp and os.path.exists(tmp):
            os.unlink(tmp)
    return time.perf_counter() - t0, None


def _publish(tmp: str, target: str, rep) -> None:
    """Move a closed recording into place (atomic rename)."""
    import os
    os.replace(tmp, target)
    rep.info(f"recorded {target} ({Path(target).stat().st_size / 2**20:.1f} MB); view it with: crowdcam view {target}")


@dataclasses.dataclass
class _LiveSession:
    """A run being served live; the recording file (if any) is published when it ends."""
    web: object
    rec: object
    tmp: str | None
    target: str | None
    rep: Reporter


def _serve_live(live: _LiveSession) -> None:
    import os

    from crowdcam.rerun_web import wait_until_interrupted
    try:
        wait_until_interrupted(announce=f"Rerun web viewer: {live.web.url}  (Ctrl-C to stop)")
    finally:
        live.rec.disconnect()                   # also writes the file's footer
        live.web.close()
        if live.tmp:
            if os.path.exists(live.tmp):
                _publish(live.tmp, live.target, live.rep)


def cmd_view(args) -> int:
    from crowdcam.rerun_web import RerunWeb, push_file, wait_until_interrupted

    path = Path(args.file)
    if not path.is_file():
        raise CliError(f"{path}: no such recording")
    try:
        from pipeline.rerun_log import read_blueprint_desc
        read_blueprint_desc(path)
    except Exception as e:          # a truncated or foreign file: one line, no traceback
        raise CliError(f"{path}: not a readable crowdcam recording ({e})") from None
    with RerunWeb(web_port=args.port) as web:
        rec = push_file(web, path)
        try:
            wait_until_interrupted(announce=f"Rerun web viewer: {web.url}  (Ctrl-C to stop)")
        finally:
            rec.disconnect()
    return 0


def _check_host(host: str) -> None:
    """An address this machine can serve on (viser would otherwise wait silently)."""
    import socket
    try:
        info = socket.getaddrinfo(host, 0, type=socket.SOCK_STREAM)[0]
        with socket.socket(info[0], socket.SOCK_STREAM) as s:
            s.bind(info[4][:2])
    except (OSError, UnicodeError) as e:
        raise CliError(f"--host {host}: cannot serve on this address ({getattr(e, 'strerror', None) or e})") from None


def cmd_inspect(args) -> int:
    from pipeline.loading import is_inside, load_gts, load_set

    rep = Reporter(args.quiet)
    params = _params(args)
    set_dir = Path(args.set) if args.set else SAMPLE_SETS / "tabletop_ball"
    if not 0 <= args.port <= 65535:
        raise CliError(f"--port must be in 0..65535 (got {args.port})")
    _check_host(args.host)
    photo_set = load_set(set_dir, params.max_side, warn=rep.warn, gt_dir=Path(args.gt) if args.gt else None)
    params = params.for_working_side(photo_set.working_side)
    gts = load_gts(photo_set)
    out = Path(args.out) if args.out else Path.cwd() / "crowdcam-out" / photo_set.name / "inspector"
    if is_inside(out, set_dir):
        raise CliError(f"{out}: the output folder must not be inside the input folder {set_dir}")
    from crowdcam.rerun_web import wait_until_interrupted
    from inspector.app import Inspector
    try:
        app = Inspector(photo_set, gts, _cache(args, rep), out, host=args.host, port=args.port, preset=args.preset,
                        max_side=params.max_side, workers=args.workers, changes=tuple(args.param or ()))
    except OSError as e:
        raise CliError(f"cannot serve on {args.host}:{args.port}: {e.strerror or e}") from None
    if args.host not in ("127.0.0.1", "localhost", "::1"):
        rep.warn(f"serving on {args.host}: anyone who can reach this machine can open the inspector")
    try:
        wait_until_interrupted(announce=f"crowdcam inspector: {app.url}  ({photo_set.name}, "
                                        f"{len(photo_set.photos)} photos; Ctrl-C to stop)")
    finally:
        app.close()
    return 0


def cmd_eval(args) -> int:
    import numpy as np
    from pipeline.cache import atomic_write_bytes
    from pipeline.evaluate import score_set, static_false_positive_rate
    from pipeline.loading import load_gt

    out = Path(args.dir)
    summary_path = out / "summary.json"
    if not summary_path.exists():
        raise CliError(f"{out}: not a crowdcam output folder (no summary.json)")
    try:
        summary = json.loads(summary_path.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise CliError(f"{summary_path}: unreadable ({e})") from None
    gt_dir = Path(args.gt) if args.gt else Path(summary["input"]) / "gt"
    if not gt_dir.is_dir():
        raise CliError(f"{gt_dir}: no ground-truth folder (give one with --gt)")
    probs, gts = {}, {}
    for im in summary["images"]:
        mp = out / "maps" / f"{im['stem']}.npy"
        if not im.get("has_map") or not mp.exists():
            continue
        g = load_gt(gt_dir, im["stem"], tuple(im["size"]))
        if g is None:
            continue
        probs[im["stem"]], gts[im["stem"]] = np.load(mp), g
    if not probs:
        raise CliError(f"{gt_dir}: no ground-truth mask matches a map in {out}")
    mask_threshold = float(summary.get("threshold", 0.5))     # the one the run's masks were cut at
    score = score_set(probs, gts, mask_threshold)
    fp = static_false_positive_rate(probs, gts, 0.5)
    print(_table_row(summary["set"], score))
    print(f"{'':<20} static pixels above 0.5: {fp:.1%}")
    result = {"set": summary["set"], "gt": str(gt_dir), **score.to_dict(), "static_fp_rate_at_0.5": fp}
    atomic_write_bytes(out / "eval.json", json.dumps(result, indent=1).encode())
    return 0


def cmd_bench(args) -> int:
    from crowdcam.bench import run_bench
    sets = [Path(s) for s in args.sets] or sorted(p for p in SAMPLE_SETS.iterdir() if (p / "images").is_dir())
    if not sets:
        raise CliError(f"{SAMPLE_SETS}: no sample sets found")
    for s in sets:
        if not s.is_dir():
            raise CliError(f"{s}: no such folder")
    presets = args.preset or ["default"]
    if args.param and args.ui:
        raise CliError("--param applies to the timed runs, not to --ui (it times the presets as they are)")
    if args.ui:
        from crowdcam.bench import print_ui_latency, ui_latency
        rows = [ui_latency(s, presets[0], args.max_side, tour_rounds=args.tour_rounds) for s in sets]
        print_ui_latency(rows)
        return 0
    from pipeline.params import get_preset
    for preset in presets:             # a bad setting is one line now, not an error row per set later
        try:
            get_preset(preset).with_settings(args.param or [])
        except ValueError as e:
            raise CliError(str(e)) from None
    out = Path(args.json) if args.json else Path.cwd() / "crowdcam-out" / "bench.json"
    _check_max_supports(args.max_supports)
    if args.dask is not None and args.dask < 1:
        raise CliError(f"--dask {args.dask}: give the number of worker processes (1 or more)")
    return run_bench(sets, presets, args.max_side, args.workers, out, quiet=args.quiet, settings=args.param or [],
                     max_supports=args.max_supports, dask_workers=args.dask or 0)


def cmd_make_samples(args) -> int:
    from crowdcam.scenegen import SETS, write_set
    names = args.only or [k for k, spec in SETS.items() if spec.bundled]
    for n in names:
        if n not in SETS:
            raise CliError(f"unknown sample set {n!r}; choose from {', '.join(SETS)}")
    out = Path(args.out)
    for n in names:
        t = time.perf_counter()
        write_set(SETS[n], out / n, scale=args.scale)
        print(f"{out / n}: {SETS[n].n_cameras} photos in {time.perf_counter() - t:.1f} s", file=sys.stderr)
    return 0


def cmd_calibrate(args) -> int:
    from crowdcam.calibrate import main as calibrate
    rep = Reporter(args.quiet)
    params = _params(args)
    for d in args.sets:
        if Path(d).resolve().is_relative_to(SAMPLE_SETS.resolve()):
            raise CliError(f"{d}: a bundled sample set; calibrate on other sets (or --render N) and test on these")
    result = calibrate([Path(d) for d in args.sets], args.render, Path(args.out), params, _cache(args),
                       args.workers, rep.progress)
    rep.close()
    fo = result["final_offset"]
    print(json.dumps({"calib_scale": result["calib_scale"], "calib_offset": result["calib_offset"],
                      "mean_jaccard_opt_per_set": round(fo["mean_jaccard_opt_per_set"], 4),
                      "best_threshold": fo["best_threshold"]}))
    for r in result["reliability"]:
        share = "–" if r["moving_share"] is None else f"{r['moving_share']:.2f}"
        print(f"P_dynamic {r['p_from']:.1f}-{r['p_to']:.1f}: {r['pixels']:>9} px, moving {share}")
    return 0


def cmd_cache(args) -> int:
    from pipeline.cache import PairCache, default_cache_dir
    root = Path(args.cache_dir) if args.cache_dir else default_cache_dir()
    cache = PairCache(root)
    if args.action == "clear":
        n = cache.clear()
        print(f"{root}: deleted {n} entries")
        return 0
    entries = cache.entries()
    kinds: dict[str, list[int]] = {}
    for p, b, _ in entries:
        kinds.setdefault(p.parent.parent.name, []).append(b)
    print(f"{root}: {len(entries)} entries, {sum(b for _, b, _ in entries) / 2**20:.1f} MB")
    for k, sizes in sorted(kinds.items()):
        print(f"  {k:<10} {len(sizes):>6} entries  {sum(sizes) / 2**20:9.1f} MB")
    return 0


# ----------------------------------------------------------------------------- parser
def build_parser() -> argparse.ArgumentParser:
    from pipeline.params import PRESETS
    ap = argparse.ArgumentParser(prog="crowdcam", description="Detect moving regions in CrowdCam photo sets.")
    sub = ap.add_subparsers(dest="command", required=True)

    def common(p, cache=True):
        p.add_argument("--preset", default="default", choices=sorted(PRESETS),
                       help="parameter preset: default (ours) or paper (the paper's method unchanged)")
        p.add_argument("--max-side", type=int, default=None,
                       help="working resolution: photos are resized so that their longer side is at most this "
                            f"(px; default {DEFAULT_MAX_SIDE}; 640 for a first look about 3x faster on larger photos)")
        p.add_argument("--workers", type=int, default=None, help="processes (default: all cores)")
        p.add_argument("--quiet", action="store_true", help="no progress output")
        if cache:
            p.add_argument("--cache-dir", default=None, help="per-pair cache (default ~/.cache/crowdcam or $CROWDCAM_CACHE)")
            p.add_argument("--no-cache", action="store_true", help="neither read nor write the cache")
            p.add_argument("--cache-max-gb", type=float, default=5.0,
                           help="evict the least recently used cache entries beyond this size (default 5)")

    d = sub.add_parser("detect", help="compute dynamic-probability maps and masks for a photo set")
    d.add_argument("set", help="folder of photos, or folder with images/ (and optional gt/)")
    d.add_argument("--out", default=None, help="output folder (default ./crowdcam-out/<set name>)")
    d.add_argument("--threshold", type=float, default=None, help="mask threshold on P_dynamic (default 0.5)")
    d.add_argument("--gt", default=None, metavar="DIR",
                   help="ground-truth masks <photo stem>.png (default: gt/ beside the photos or beside images/)")
    d.add_argument("--max-supports", type=int, default=None, metavar="K",
                   help="at most K supports per photo, the best by geometry and viewpoint (default: 8 for sets of "
                        "more than 9 photos, no cap below; 0: no cap)")
    d.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT",
                   help="run the per-pair work on a Dask distributed cluster (README: Beyond one machine)")
    d.add_argument("--export-colmap", default=None, metavar="DIR",
                   help="write the set's reconstruction (cameras, sparse points) in COLMAP's text format")
    d.add_argument("--rrd", default=None, help="record the run's internals to this Rerun file")
    d.add_argument("--rerun-web", action="store_true", help="stream the run to Rerun's web viewer and serve it")
    d.add_argument("--rr-ref", default=None, help="reference photo (stem) shown first in Rerun")
    d.add_argument("--rr-pixel", action="append", help="X,Y (working pixels) of the reference to explain in Rerun")
    d.add_argument("--param", action="append", metavar="SECTION.FIELD=VALUE",
                   help="change one setting of the preset (repeatable), e.g. sweep.min_agree=2 "
                        "(pipeline/params.py lists them; summary.json records them all)")
    common(d)
    d.set_defaults(fn=cmd_detect)

    v = sub.add_parser("view", help="serve a Rerun recording in the web viewer on 127.0.0.1")
    v.add_argument("file", help="a .rrd file written by `crowdcam detect --rrd`")
    v.add_argument("--port", type=int, default=None, help="web viewer port (default: a free one)")
    v.set_defaults(fn=cmd_view)

    ins = sub.add_parser("inspect", help="explore a set in the browser: maps, supports, thresholds, evidence")
    ins.add_argument("set", nargs="?", default=None,
                     help="folder of photos, or folder with images/ and gt/ (default: bundled tabletop_ball)")
    ins.add_argument("--host", default="127.0.0.1",
                     help="address to serve on (default 127.0.0.1: this machine only; other addresses must be given "
                          "explicitly)")
    ins.add_argument("--port", type=int, default=8080, help="port (default 8080; the next free one if taken)")
    ins.add_argument("--gt", default=None, metavar="DIR",
                     help="ground-truth masks <photo stem>.png (default: gt/ beside the photos or beside images/)")
    ins.add_argument("--out", default=None,
                     help="where 'Save to output folder' writes (default ./crowdcam-out/<set name>/inspector)")
    ins.add_argument("--param", action="append", metavar="SECTION.FIELD=VALUE",
                     help="change one setting of every preset the inspector runs (repeatable), e.g. "
                          "geometry.affine_tilts=2 or aggregate.threshold=0.2 (the slider's start)")
    common(ins)
    ins.set_defaults(fn=cmd_inspect)

    e = sub.add_parser("eval", help="Jaccard of a detect output against ground truth (Table 1 row)")
    e.add_argument("dir", help="output folder of `crowdcam detect`")
    e.add_argument("--gt", default=None, help="ground-truth folder (default: the input set's gt/)")
    e.set_defaults(fn=cmd_eval)

    b = sub.add_parser("bench", help="time and score the bundled sample sets (or the given sets)")
    b.add_argument("sets", nargs="*", help="set folders (default: all bundled sample sets)")
    b.add_argument("--preset", action="append", choices=sorted(PRESETS), help="repeat to compare presets")
    b.add_argument("--max-side", type=int, default=DEFAULT_MAX_SIDE)
    b.add_argument("--workers", type=int, default=None)
    b.add_argument("--json", default=None, help="where to write the JSON report (default ./crowdcam-out/bench.json)")
    b.add_argument("--quiet", action="store_true")
    b.add_argument("--param", action="append", metavar="SECTION.FIELD=VALUE",
                   help="change one setting of every preset run (repeatable), e.g. sweep.min_agree=2")
    b.add_argument("--max-supports", type=int, default=None, metavar="K",
                   help="at most K supports per photo (as crowdcam detect; default: 8 for sets of more than 9 "
                        "photos, no cap below; 0: no cap)")
    b.add_argument("--dask", type=int, default=None, metavar="N",
                   help="also run each set cold on a local Dask cluster of N worker processes: its time "
                        "against the pool's, and the largest difference of the maps")
    b.add_argument("--ui", action="store_true",
                   help="measure the inspector's main-view update and tour-step latency instead (uses the cache)")
    b.add_argument("--tour-rounds", type=int, default=3,
                   help="with --ui: walks through the tour's seven steps to time (0: none; default 3)")
    b.set_defaults(fn=cmd_bench)

    cc = sub.add_parser("cache", help="show the size of the cache, or clear it")
    cc.add_argument("action", choices=("info", "clear"))
    cc.add_argument("--cache-dir", default=None, help="the cache (default ~/.cache/crowdcam or $CROWDCAM_CACHE)")
    cc.set_defaults(fn=cmd_cache)

    c = sub.add_parser("calibrate", help="fit the default preset's probability calibration on rendered sets")
    c.add_argument("sets", nargs="*", help="calibration set folders with gt/ (never the bundled ones)")
    c.add_argument("--render", type=int, default=0, help="render this many calibration sets (other seeds)")
    c.add_argument("--out", default="crowdcam-out/calibration", help="where rendered sets and the result go")
    common(c)
    c.set_defaults(fn=cmd_calibrate)

    from crowdcam.report import add_parser as add_report_parser
    add_report_parser(sub, common)

    m = sub.add_parser("make-samples", help="render the bundled synthetic sample sets")
    m.add_argument("--out", default=str(SAMPLE_SETS))
    m.add_argument("--only", action="append",
                   help="render only this set (repeatable; plaza_crowd_100, the 100-photo scale benchmark, only so)")
    m.add_argument("--scale", type=float, default=1.0, help="image size factor (tests use small sets)")
    m.set_defaults(fn=cmd_make_samples)
    return ap


class Terminated(KeyboardInterrupt):
    """SIGTERM (a `kill`, a job scheduler's stop), raised where the run is, so that it stops as it
    does on Ctrl-C: the workers terminated, no output half-written, the finished pairs cached.
    Without it the default action ended the main process at once and left its pool's workers
    behind, idle, for ever."""


def _raise_terminated(signum, frame):
    raise Terminated()


RESOURCE_TRACKER_WARNINGS = "ignore:resource_tracker:UserWarning"


def quiet_resource_tracker() -> None:
    """Keep multiprocessing's resource tracker from printing its exit warnings to our stderr.

    The tracker is a helper process that the first pool starts; at its exit it unlinks the
    semaphores still registered with it and warns about each. After a stop (SIGTERM, Ctrl-C),
    a semaphore whose cleanup was cut off between its unlink and its unregistration is reported
    as "leaked ... [Errno 2] No such file or directory" although nothing is left (one CI run in a
    clean clone: four lines of warnings after the stop's one line). Whatever it finds, it cleans;
    the user gets our one line. The tracker takes our warning options (-W) on its command line
    when it starts, so this must come before the first pool."""
    if RESOURCE_TRACKER_WARNINGS not in sys.warnoptions:
        sys.warnoptions.append(RESOURCE_TRACKER_WARNINGS)


def main(argv: list[str] | None = None) -> int:
    ap = build_parser()
    args = ap.parse_args(argv)
    quiet_resource_tracker()
    from pipeline.loading import InputError
    from pipeline.run import SchedulerError, WorkerDied
    previous = None
    if threading.current_thread() is threading.main_thread():
        previous = signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        return args.fn(args)
    except Terminated:
        print("crowdcam: terminated (SIGTERM); the finished pairs are cached, a re-run resumes", file=sys.stderr)
        return 143
    except (InputError, CliError, SchedulerError) as e:
        print(f"crowdcam: error: {one_line(e)}", file=sys.stderr)
        return EXIT_USAGE
    except WorkerDied as e:
        print(f"crowdcam: error: {one_line(e)}", file=sys.stderr)
        return EXIT_FAULT
    except OSError as e:                 # disk full, permissions: the output staging is already removed
        where = f"{e.filename}: " if getattr(e, "filename", None) else ""
        print(f"crowdcam: error: {one_line(where + str(e.strerror or e))}", file=sys.stderr)
        return EXIT_FAULT
    except KeyboardInterrupt:
        print("crowdcam: interrupted", file=sys.stderr)
        return 130
    except MemoryError:
        print("crowdcam: error: out of memory (try a smaller --max-side)", file=sys.stderr)
        return 1
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


if __name__ == "__main__":
    sys.exit(main())
