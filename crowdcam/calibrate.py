"""Calibrate the default preset's fused evidence into a probability (`crowdcam calibrate`).

The default preset sums static log-odds z over its cues (Eq. 3's per-support terms and the
depth-consistent cue, pipeline/run.py). A sum of log-odds from cues that are not independent is
not a probability yet (EVIDENCE_NOTES point 6). We map it by P_dynamic = 1 / (1 + e^(s (z - z0))):

- z0 is the threshold on z that maximises the mean Jaccard over the calibration sets (§4.2), so
  that the best threshold on P_dynamic sits at 0.5 (a pixel no support speaks about is set to 0.5
  by the pipeline whatever z0 is: no evidence never reads as motion);
- s is the slope of a logistic regression of "moving" on z, so that P_dynamic changes as fast as
  the frequency of movers does around it.

Fit on rendered sets that are *not* bundled (make them with `--render N`, other seeds of the
generator's sets), then write the two numbers into pipeline/params.py (AggregateParams.calib_*).
It also prints the reliability curve: per bin of P_dynamic, the share of pixels that are moving.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import cv2
import numpy as np

from pipeline.evaluate import jaccard_curve


def render_sets(out: Path, n: int) -> list[Path]:
    """Render n calibration sets (the generator's sets with other seeds) into out/."""
    from crowdcam.scenegen import SETS, write_set
    bases = [s for s in ("square_people", "tabletop_ball", "street_sideways", "arc_wide_ground", "plaza_many",
                         "courtyard_static") if s in SETS]
    paths = []
    for k in range(n):
        base = SETS[bases[k % len(bases)]]
        spec = dataclasses.replace(base, name=f"{base.name}_calib{k}", seed=10_000 + 17 * k)
        path = out / spec.name
        if not (path / "cameras.json").exists():
            write_set(spec, path)
        paths.append(path)
    return paths


def collect(set_dirs: list[Path], params, cache, workers=None, progress=None):
    """Per photo with ground truth: (z (h, w) float32 static log-odds, moving (h, w) bool, care
    (h, w) bool) at working resolution."""
    from pipeline.loading import load_gts, load_set
    from pipeline.run import detect_set
    out = []
    for d in set_dirs:
        ps = load_set(d, params.max_side)
        gts = load_gts(ps)
        res = detect_set(ps, params, cache, workers=workers, progress=progress)
        for i, p in enumerate(ps.photos):
            if not res.supports[i] or p.stem not in gts:
                continue
            h, w = p.size
            gt = cv2.resize(gts[p.stem], (w, h), interpolation=cv2.INTER_NEAREST)
            out.append((res.static_log_odds(i, res.supports[i]), gt == 255, gt != 128, d.name))
    return out


def fit(samples) -> dict:
    """z0 (best mean-Jaccard threshold on z), s (logistic slope) and the reliability curve."""
    grid = np.linspace(-12, 12, 481)
    by_set: dict[str, list] = {}
    for z, moving, care, name in samples:
        if moving.any():
            # prediction "moving" when z < t  <=>  -z > -t: jaccard_curve on -z with thresholds -grid
            gt = np.where(care, np.where(moving, 255, 0), 128).astype(np.uint8)
            by_set.setdefault(name, []).append(jaccard_curve(-z, gt, -grid[::-1])[::-1])
    curves = np.array([np.mean(c, axis=0) for c in by_set.values()])
    mean = curves.mean(axis=0)
    best_z = float(grid[int(np.argmax(mean))])
    z0 = best_z
    zs = np.concatenate([z[care][::5] for z, _, care, _ in samples]).astype(np.float64)
    ys = np.concatenate([m[care][::5] for _, m, care, _ in samples]).astype(np.float64)
    X = np.column_stack([np.ones_like(zs), zs])
    wgt = np.zeros(2)
    for _ in range(50):                          # Newton's method for the logistic regression
        p = 1.0 / (1.0 + np.exp(-(X @ wgt)))
        H = (X * (p * (1 - p))[:, None]).T @ X + 1e-6 * np.eye(2)
        wgt -= np.linalg.solve(H, X.T @ (p - ys))
    s = float(-wgt[1])
    prob = 1.0 / (1.0 + np.exp(s * (zs - z0)))
    bins = np.linspace(0, 1, 11)
    idx = np.clip(np.digitize(prob, bins) - 1, 0, 9)
    rel = [{"p_from": float(bins[k]), "p_to": float(bins[k + 1]), "pixels": int((idx == k).sum()),
            "moving_share": float(ys[idx == k].mean()) if (idx == k).any() else None} for k in range(10)]
    return {"calib_offset": round(z0, 3), "calib_scale": round(s, 3), "best_mean_jaccard": float(mean.max()),
            "best_z": best_z, "mean_jaccard_at_offset": float(mean[int(np.argmin(np.abs(grid - z0)))]),
            "sets": sorted(by_set), "reliability": rel}


def main(set_dirs: list[Path], render: int, out: Path, params, cache, workers=None, progress=None) -> dict:
    if render:
        set_dirs = list(set_dirs) + render_sets(out, render)
    if not set_dirs:
        raise ValueError("give calibration sets (folders with images/ and gt/) or --render N")
    base = params.replace(aggregate=dataclasses.replace(params.aggregate, calib_scale=1.0, calib_offset=0.0))
    result = fit(collect(set_dirs, base, cache, workers, progress))
    out.mkdir(parents=True, exist_ok=True)
    (out / "calibration.json").write_text(json.dumps(result, indent=1))
    return result
