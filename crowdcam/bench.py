"""`crowdcam bench`: time and score sets, each preset in a fresh process for honest cold figures.

Per set and preset: images, ordered pairs, cold wall seconds (empty cache, including worker
start-up), seconds per ordered pair, warm seconds (everything from the cache), peak resident
memory (main process and largest worker), the Jaccard (optimised per image and per set) when the
set has ground truth, and the share of static pixels above 0.5.
"""

from __future__ import annotations

import json
import multiprocessing as mp
import resource
import sys
import tempfile
import time
from pathlib import Path


def _bench_one(set_dir: str, preset: str, max_side: int, workers: int | None, q) -> None:
    try:
        from pipeline.cache import PairCache
        from pipeline.evaluate import score_set, static_false_positive_rate
        from pipeline.loading import load_gt, load_set
        from pipeline.output import to_original
        from pipeline.params import get_preset
        from pipeline.run import detect_set

        params = get_preset(preset).replace(max_side=max_side)
        with tempfile.TemporaryDirectory(prefix="crowdcam-bench-") as tmp:
            cache = PairCache(Path(tmp))
            t0 = time.perf_counter()
            ps = load_set(Path(set_dir), params.max_side)
            res = detect_set(ps, params, cache, workers=workers)
            cold = time.perf_counter() - t0
            t1 = time.perf_counter()
            ps2 = load_set(Path(set_dir), params.max_side)
            detect_set(ps2, params, cache, workers=workers)
            warm = time.perf_counter() - t1
        row = {"set": ps.name, "preset": preset, "images": len(ps.photos), "ordered_pairs": len(res.pair_results),
               "rejected_pairs": sum(not g.ok for (i, j), g in res.pairs.items() if i < j),
               "cold_s": cold, "s_per_pair": cold / max(1, len(res.pair_results)), "warm_s": warm,
               "timings": res.timings}
        probs, gts = {}, {}
        for p, d in zip(ps.photos, res.dynamic):
            if d is None:
                continue
            probs[p.stem] = to_original(d, p)
            if ps.gt_dir is not None:
                g = load_gt(ps.gt_dir, p.stem, p.orig_size)
                if g is not None:
                    gts[p.stem] = g
        if gts:
            sc = score_set({k: v for k, v in probs.items() if k in gts}, gts)
            row.update(jaccard_opt_image=sc.mean_opt_image, jaccard_opt_image_std=sc.std_opt_image,
                       jaccard_opt_set=sc.mean_opt_set, jaccard_opt_set_std=sc.std_opt_set,
                       has_motion=sc.n_with_motion > 0)
        row["static_fp_rate"] = static_false_positive_rate(probs, gts or None, 0.5)
        row["peak_mb_main"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        row["peak_mb_worker"] = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
        q.put(row)
    except Exception as e:       # reported as a row, the bench goes on
        q.put({"set": Path(set_dir).name, "preset": preset, "error": f"{type(e).__name__}: {e}"})


def run_bench(sets: list[Path], presets: list[str], max_side: int, workers: int | None, out: Path,
              quiet: bool = False) -> int:
    from pipeline.cache import atomic_write_bytes

    ctx = mp.get_context("spawn")
    rows = []
    head = (f"{'set':<20} {'preset':<8} {'imgs':>4} {'pairs':>5} {'cold s':>7} {'s/pair':>7} {'warm s':>7} "
            f"{'peak MB':>9} {'J img':>11} {'J set':>11} {'static>0.5':>10}")
    print(head)
    for s in sets:
        for preset in presets:
            q = ctx.Queue()
            p = ctx.Process(target=_bench_one, args=(str(s), preset, max_side, workers, q))
            p.start()
            row = q.get()
            p.join()
            rows.append(row)
            if "error" in row:
                print(f"{row['set']:<20} {preset:<8} error: {row['error']}")
                continue
            ji = (f"{row['jaccard_opt_image']:.2f}±{row['jaccard_opt_image_std']:.2f}"
                  if row.get("has_motion") else "-")
            js = f"{row['jaccard_opt_set']:.2f}±{row['jaccard_opt_set_std']:.2f}" if row.get("has_motion") else "-"
            print(f"{row['set']:<20} {preset:<8} {row['images']:>4} {row['ordered_pairs']:>5} {row['cold_s']:>7.1f} "
                  f"{row['s_per_pair']:>7.2f} {row['warm_s']:>7.2f} "
                  f"{row['peak_mb_main']:>4.0f}/{row['peak_mb_worker']:<4.0f} {ji:>11} {js:>11} "
                  f"{row['static_fp_rate']:>10.1%}")
            sys.stdout.flush()
    atomic_write_bytes(out, json.dumps({"max_side": max_side, "rows": rows}, indent=1).encode())
    if not quiet:
        print(f"wrote {out}", file=sys.stderr)
    return 0 if all("error" not in r for r in rows) else 1
