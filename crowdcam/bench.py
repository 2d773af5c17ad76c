"""`crowdcam bench`: time and score sets, each preset in a fresh process for honest cold figures.

Per set and preset: images, ordered pairs, cold wall seconds (empty cache, including worker
start-up), seconds per ordered pair (the whole cold run's, and the pairs' stage's alone), warm
seconds (everything from the cache), peak resident memory (main process and largest worker), the
Jaccard (optimised per image and per set) when the set has ground truth, the share of static
pixels above 0.5, and, for the generator's synthetic sets (with cameras.json), the precision of
the admitted epipolar pairs' F against the true cameras (crowdcam/truth.py): share of pairs with
median error < 2 px / pairs with 90th percentile > 10 px / median of the pairs' medians in px.

With --dask N, the same child then runs the set again, cold with its own cache, on a Dask
LocalCluster of N worker processes (one thread each; started before the clock, as a cluster a user
starts with `dask worker` would be), and reports its wall time against the pool's and the largest
difference between the two runs' maps (the README's target: 0, and at most 1.3x the pool's time).
"""

from __future__ import annotations

import json
import multiprocessing as mp
import resource
import sys
import tempfile
import time
from pathlib import Path

from pipeline.params import DEFAULT_MAX_SIDE


def _bench_one(set_dir: str, preset: str, max_side: int, workers: int | None, q, settings: tuple = (),
               max_supports: int | None = None, dask_workers: int = 0) -> None:
    try:
        from pipeline.cache import PairCache
        from pipeline.evaluate import score_set, static_false_positive_rate
        from pipeline.loading import load_gts, load_set
        from pipeline.output import to_original
        from pipeline.params import get_preset
        from pipeline.run import detect_set

        params = get_preset(preset).replace(max_side=max_side).with_settings(list(settings))
        with tempfile.TemporaryDirectory(prefix="crowdcam-bench-") as tmp:
            cache = PairCache(Path(tmp))
            t0 = time.perf_counter()
            ps = load_set(Path(set_dir), params.max_side)
            params = params.for_working_side(ps.working_side)
            res = detect_set(ps, params, cache, workers=workers, max_supports=max_supports)
            cold = time.perf_counter() - t0
            t1 = time.perf_counter()
            ps2 = load_set(Path(set_dir), params.max_side)
            detect_set(ps2, params, cache, workers=workers, max_supports=max_supports)
            warm = time.perf_counter() - t1
        n_pairs = len(res.pair_results)
        row = {"set": ps.name, "preset": preset, "settings": list(settings), "images": len(ps.photos),
               "working_side": params.max_side,
               "max_supports": max_supports, "ordered_pairs": n_pairs,
               "rejected_pairs": sum(not g.ok for (i, j), g in res.pairs.items() if i < j),
               "cold_s": cold, "s_per_pair": cold / max(1, n_pairs),
               # the pairs' stage alone per pair: what a pair costs, without the set's fixed costs
               # (features, geometry, cameras, worker start-up, the maps)
               "pair_stage_s_per_pair": res.timings.get("pairs_s", 0.0) / max(1, n_pairs),
               "warm_s": warm, "timings": res.timings}
        probs = {p.stem: to_original(d, p) for p, d in zip(ps.photos, res.dynamic) if d is not None}
        gts = {k: g for k, g in load_gts(ps).items() if k in probs}
        if gts:
            sc = score_set({k: v for k, v in probs.items() if k in gts}, gts, params.aggregate.threshold)
            row.update(jaccard_opt_image=sc.mean_opt_image, jaccard_opt_image_std=sc.std_opt_image,
                       jaccard_opt_set=sc.mean_opt_set, jaccard_opt_set_std=sc.std_opt_set,
                       best_threshold=sc.set_threshold, has_motion=sc.n_with_motion > 0,
                       jaccard_at_mask=sc.mean_at_mask, mask_threshold=sc.mask_threshold)
        row["static_fp_rate"] = static_false_positive_rate(probs, gts or None, 0.5)
        row["peak_mb_main"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        row["peak_mb_worker"] = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
        # After the memory peaks: rendering the truth is the bench's work, not the method's.
        row.update(_f_precision(res))
        if dask_workers:
            row["dask"] = _dask_run(set_dir, params, res, cold, dask_workers, max_supports)
        q.put(row)
    except Exception as e:       # reported as a row, the bench goes on
        q.put({"set": Path(set_dir).name, "preset": preset, "error": f"{type(e).__name__}: {e}"})


def _dask_run(set_dir: str, params, pool_res, pool_cold: float, n_workers: int, max_supports: int | None) -> dict:
    """The set once more, cold (a cache of its own), on a LocalCluster of n_workers processes:
    its wall time (the cluster started beforehand), the cluster's start, and the largest absolute
    difference between its maps and the pool run's (pool_res)."""
    import numpy as np
    from distributed import LocalCluster

    from pipeline.cache import PairCache
    from pipeline.loading import load_set
    from pipeline.run import detect_set

    t0 = time.perf_counter()
    with LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        started = time.perf_counter() - t0
        with tempfile.TemporaryDirectory(prefix="crowdcam-bench-dask-") as tmp:
            t1 = time.perf_counter()
            ps = load_set(Path(set_dir), params.max_side)
            res = detect_set(ps, params, PairCache(Path(tmp)), scheduler=cluster.scheduler_address,
                             max_supports=max_supports)
            cold = time.perf_counter() - t1
    same_maps = all((a is None) == (b is None) for a, b in zip(pool_res.dynamic, res.dynamic))
    diffs = [float(np.abs(a - b).max()) for a, b in zip(pool_res.dynamic, res.dynamic)
             if a is not None and b is not None]
    return {"workers": n_workers, "cold_s": cold, "cluster_start_s": started, "vs_pool": cold / pool_cold,
            "same_photos_mapped": same_maps, "max_abs_diff": max(diffs, default=0.0),
            "timings": res.timings}


def _f_precision(res) -> dict:
    """{"f_precision": truth.f_precision(res)} (None for sets without cameras.json), plus
    "f_precision_note" when the truth is there but cannot be used (the row stays valid)."""
    from crowdcam.truth import f_precision
    try:
        return {"f_precision": f_precision(res)}
    except Exception as e:      # an evaluation aside must not cost the row its timings
        return {"f_precision": None, "f_precision_note": f"{type(e).__name__}: {e}"}


def _f_cell(fp: dict | None) -> str:
    """share of pairs with median < 2 px / pairs with p90 > 10 px / median of medians, or "–"."""
    if not fp or not fp["n_measured"]:
        return "–"
    return f"{fp['share_median_below_2px']:.0%}/{fp['n_p90_above_10px']}/{fp['median_of_medians_px']:.2f}"


def run_bench(sets: list[Path], presets: list[str], max_side: int, workers: int | None, out: Path,
              quiet: bool = False, settings: list[str] = (), max_supports: int | None = None,
              dask_workers: int = 0) -> int:
    from pipeline.cache import atomic_write_bytes

    ctx = mp.get_context("spawn")
    rows = []
    head = (f"{'set':<20} {'preset':<15} {'imgs':>4} {'px':>5} {'pairs':>5} {'cold s':>7} {'s/pair':>7} {'pair s':>7} "
            f"{'warm s':>7} {'peak MB':>9} {'J img':>11} {'J set':>11} {'thr':>5} {'J@0.5':>6} {'static>0.5':>10} "
            f"{'F <2px/p90>10/med':>17}")
    if settings:
        print("settings changed from the presets:", " ".join(settings))
    if max_supports is not None:
        print(f"supports per photo: at most {max_supports}" if max_supports else "supports per photo: no cap")
    print("px: the working size (longer side) the set ran at; s/pair: cold seconds / ordered pairs, end to end; "
          "pair s: the pairs' stage alone / ordered pairs; J@0.5: the mean Jaccard of the masks as written, "
          "at their fixed threshold (aggregate.threshold, 0.5 unless changed with --param)")
    print(head)
    for s in sets:
        for preset in presets:
            q = ctx.Queue()
            p = ctx.Process(target=_bench_one, args=(str(s), preset, max_side, workers, q, tuple(settings),
                                                     max_supports, dask_workers))
            p.start()
            row = q.get()
            p.join()
            rows.append(row)
            if "error" in row:
                print(f"{row['set']:<20} {preset:<15} error: {row['error']}")
                continue
            ji = (f"{row['jaccard_opt_image']:.2f}±{row['jaccard_opt_image_std']:.2f}"
                  if row.get("has_motion") else "-")
            js = f"{row['jaccard_opt_set']:.2f}±{row['jaccard_opt_set_std']:.2f}" if row.get("has_motion") else "-"
            thr = f"{row['best_threshold']:.2f}" if row.get("has_motion") else "-"
            at_mask = f"{row['jaccard_at_mask']:.2f}" if row.get("has_motion") else "-"
            print(f"{row['set']:<20} {preset:<15} {row['images']:>4} {row['working_side']:>5} "
                  f"{row['ordered_pairs']:>5} {row['cold_s']:>7.1f} {row['s_per_pair']:>7.2f} "
                  f"{row['pair_stage_s_per_pair']:>7.3f} {row['warm_s']:>7.2f} "
                  f"{row['peak_mb_main']:>4.0f}/{row['peak_mb_worker']:<4.0f} {ji:>11} {js:>11} {thr:>5} {at_mask:>6} "
                  f"{row['static_fp_rate']:>10.1%} {_f_cell(row.get('f_precision')):>17}")
            fp = row.get("f_precision")
            if fp and (fp["share_median_below_2px"] not in (None, 1.0) or fp["n_p90_above_10px"]):
                print(f"{'':<20} F by source: " + "; ".join(f"{src} {_f_cell(v)} of {v['n_measured']}"
                                                         for src, v in fp["by_source"].items()))
            dk = row.get("dask")
            if dk:
                procs = f"{dk['workers']} worker process{'es' if dk['workers'] > 1 else ''}"
                print(f"{'':<20} Dask, LocalCluster of {procs}: cold {dk['cold_s']:.1f} s "
                      f"({dk['vs_pool']:.2f}x the pool), cluster start {dk['cluster_start_s']:.1f} s, "
                      f"maps max |difference| {dk['max_abs_diff']:g}"
                      + ("" if dk["same_photos_mapped"] else ", NOT the same photos mapped"))
            if row.get("f_precision_note"):
                print(f"{'':<20} F precision not measured: {row['f_precision_note']}")
            sys.stdout.flush()
    atomic_write_bytes(out, json.dumps({"max_side": max_side, "rows": rows}, indent=1).encode())
    if not quiet:
        print(f"wrote {out}", file=sys.stderr)
    return 0 if all("error" not in r for r in rows) else 1


# ----------------------------------------------------------------------------- inspector latency
UI_KINDS = ("threshold", "support toggle", "remap", "weights", "tour step")


def _ms_summary(ms) -> dict:
    import numpy as np
    ms = np.asarray(ms, np.float64)
    return {"median_ms": float(np.median(ms)), "p95_ms": float(np.percentile(ms, 95)), "max_ms": float(ms.max()),
            "n": int(len(ms))}


def tour_latency(set_dir: Path, preset: str = "default", max_side: int = DEFAULT_MAX_SIDE, rounds: int = 3,
                 cache_dir: Path | None = None, presenter: bool = True, timeout: float = 1800.0) -> dict:
    """Server-side time from "next" to the tour step's picture sent (composed, JPEG-encoded and
    queued onto the tab's socket), on a real inspector tab without a browser (inspector.headless):
    the inspector runs in this process (the per-pair cache makes a computed set start at once),
    a headless tab connects, the run finishes and the tab settles (its gallery built), then the
    tour is started and walked 1 → 7 `rounds` times through Tour.go, the call the Next button and
    the step buttons make; each step is timed by the tour itself (Tour.step_ms: go() to the
    picture sent, or for step 1 with cameras, to the Geometry view drawn) and the tab settles
    before the next step, as when a teacher talks. The first round includes the default point's
    explanation (chosen at step 2). Returns the summary over all steps and per step."""
    import tempfile

    from inspector.app import Inspector
    from inspector.headless import HeadlessTab
    from pipeline.cache import PairCache, default_cache_dir
    from pipeline.loading import load_gts, load_set

    ps = load_set(Path(set_dir), max_side)

    def wait(pred, what: str) -> None:
        t0 = time.time()
        while not pred():
            if time.time() - t0 > timeout:
                raise TimeoutError(f"tour bench: timed out waiting for {what}")
            time.sleep(0.005)

    def settle(tab) -> None:
        draws = [tab.fast, tab.slow, tab.geo_draw, tab.gallery.draw, tab.presets.draw]
        while True:
            for d in draws:
                d.wait_idle(timeout)
            if all(d.idle() for d in draws):
                return

    with tempfile.TemporaryDirectory(prefix="crowdcam-tour-bench-") as tmp:
        app = Inspector(ps, load_gts(ps), PairCache(cache_dir or default_cache_dir()), Path(tmp), port=0,
                        preset=preset, max_side=max_side)
        try:
            with HeadlessTab(app) as tab:
                model = app.model(preset)
                wait(lambda: model.status in ("done", "failed"), "the run")
                if model.status == "failed":
                    raise RuntimeError(f"the run failed: {model.error}")
                settle(tab)
                tour = tab.tour
                steps: list[tuple[int, float]] = []

                def turn(k: int, action) -> None:
                    n, m = len(tab.events), len(tour.step_ms)
                    action()
                    wait(lambda: ("tour shown", k) in tab.events[n:] and len(tour.step_ms) > m, f"step {k}")
                    steps.append((k, tour.step_ms[-1]))
                    settle(tab)

                tour.set_presenter(presenter)
                turn(1, lambda: tour.start(1))                      # "Take the guided tour"
                for r in range(rounds):
                    if r:
                        turn(1, lambda: tour.go(1))                 # the step button "1"
                    for k in range(2, 8):
                        turn(k, lambda: tour.go(tour.step + 1))     # "Next" (or →)
                three_d = any(e == ("view", "geometry") for e in tab.events)
                tour.stop()
                settle(tab)
        finally:
            app.close()
    out = _ms_summary([ms for _, ms in steps])
    out["per_step"] = {k: _ms_summary([ms for j, ms in steps if j == k]) for k in range(1, 8)}
    out["step1_3d"] = bool(three_d)
    return out


def ui_latency(set_dir: Path, preset: str = "default", max_side: int = DEFAULT_MAX_SIDE, repeats: int = 30,
               cache_dir: Path | None = None, tour_rounds: int = 3) -> dict:
    """Server-side time of the inspector's main-view update, as a tab sees it: re-aggregate from
    the cached per-support maps (model.TermCache, through the pipeline's Eq. 2/3 functions), the
    refinement, the overlay, and the JPEG encode and send of viser's image handle.

    Measured on the reference with the most supports, all supports on, for each kind of change:
    threshold (no re-aggregation), a support toggled (sum of cached terms), and remap or weights
    (the reference's terms recomputed). Returns per-kind median / 95th percentile / max in ms,
    and the same for the tour's steps ("tour step", tour_latency; 0 rounds: not measured).
    """
    from dataclasses import replace

    import numpy as np
    import viser

    from inspector import compose, render
    from inspector.model import Settings, TermCache, first_reference
    from pipeline.cache import PairCache, default_cache_dir
    from pipeline.loading import load_set
    from pipeline.params import get_preset
    from pipeline.run import detect_set

    ps = load_set(Path(set_dir), max_side)
    params = get_preset(preset).replace(max_side=max_side).for_working_side(ps.working_side)
    max_side = params.max_side
    snap = detect_set(ps, params, PairCache(cache_dir or default_cache_dir()), workers=None)
    ref = first_reference(snap.supports)
    sups = tuple(snap.supports[ref])
    rgb = ps.photos[ref].rgb
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        handle = server.scene.add_image("/reference", rgb, render_width=rgb.shape[1] / rgb.shape[0],
                                        render_height=1.0, format="jpeg", jpeg_quality=88)
        terms = TermCache()
        base = replace(Settings.for_preset(preset, ref, max_side), supports=sups)
        layers = render.Layers()

        def update(s: Settings) -> float:
            t0 = time.perf_counter()
            img, _ = compose.main_view(snap, rgb, s, layers, terms)
            handle.image = img
            return 1000 * (time.perf_counter() - t0)

        update(base)                                   # fill the cache as the first view does
        kinds = {
            "threshold": lambda k: replace(base, threshold=0.3 + 0.4 * (k % 10) / 10),
            "support toggle": lambda k: replace(base, supports=tuple(j for j in sups if j != sups[k % len(sups)])),
            "remap": lambda k: replace(base, remap=(0.2 + 0.01 * k, 0.8 - 0.01 * k)),
            "weights": lambda k: replace(base, w_hog=1.0 + 0.1 * k),
        }
        out = {"set": ps.name, "preset": preset, "reference": ps.photos[ref].stem, "supports": len(sups),
               "size": list(rgb.shape[:2])}
        for name, make in kinds.items():
            out[name] = _ms_summary([update(make(k)) for k in range(repeats)])
    finally:
        server.stop()
    del snap, terms                                    # the tour's inspector loads the run again
    if tour_rounds:
        out["tour step"] = tour_latency(set_dir, preset, max_side, tour_rounds, cache_dir)
    return out


def print_ui_latency(rows: list[dict]) -> None:
    kinds = [k for k in UI_KINDS if any(k in r for r in rows)]
    print(f"{'set':<20} {'ref':<10} {'sup':>3} {'size':>9}  " + "  ".join(f"{k:>22}" for k in kinds))
    for r in rows:
        cells = "  ".join(f"{r[k]['median_ms']:6.1f} / {r[k]['p95_ms']:5.1f} / {r[k]['max_ms']:5.1f}" if k in r
                          else f"{'–':>22}" for k in kinds)
        print(f"{r['set']:<20} {r['reference']:<10} {r['supports']:>3} {r['size'][1]}x{r['size'][0]:<5} {cells}")
    print("(ms: median / 95th percentile / max, server-side: the main-view update for each kind of change; "
          "tour step: from \"next\" to the step's picture sent, every step of several walks through the tour)")
    for r in rows:
        t = r.get("tour step")
        if t:
            per = ", ".join(f"{k}: {v['median_ms']:.0f}/{v['max_ms']:.0f}" for k, v in t["per_step"].items())
            print(f"{r['set']:<20} tour, {t['n']} steps, median/max ms per step: {per}"
                  + (" (step 1: the cameras in 3-D)" if t.get("step1_3d") else ""))
