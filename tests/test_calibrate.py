"""crowdcam calibrate: the offset is chosen on the final maps, not on the calibrated sum alone."""

import numpy as np

from crowdcam.calibrate import final_offset, fit


def _samples(best_offset: float, n_sets: int = 2, size: int = 32):
    """Per set one photo: a square mover; its final map (0.95 on it, 0.05 elsewhere) is clean only at
    `best_offset` (elsewhere the map also lights a static band), while z, the sum before the
    refinement and the plane-aligned difference, prefers another place (z0 near 0)."""
    rng = np.random.default_rng(0)
    out = []
    for k in range(n_sets):
        moving = np.zeros((size, size), bool)
        moving[8:16, 8 + k:16 + k] = True
        care = np.ones_like(moving)
        z = np.where(moving, -0.2, 0.2) + rng.normal(0, 0.3, moving.shape)   # overlapping: a finite slope

        def final(scale, offset, moving=moving):
            p = np.where(moving, 0.95, 0.05).astype(np.float32)
            if abs(offset - best_offset) > 1e-6:
                p[20:, :] = 0.97                       # a static band lit up: a worse map
            return p
        out.append((z.astype(np.float32), moving, care, f"set{k}", final))
    return out


def test_final_offset_picks_the_offset_whose_final_maps_score_best():
    res = final_offset(_samples(0.3), scale=1.0, z0=0.0, span=0.5, step=0.1)
    assert res["offset"] == 0.3
    assert res["mean_jaccard_opt_per_set"] == 1.0             # the clean maps at 0.3: the mover exactly
    assert len(res["searched"]) == 11 and max(r["mean_jaccard_opt_per_set"] for r in res["searched"]) == 1.0
    assert all(r["mean_jaccard_opt_per_set"] < 1.0 for r in res["searched"] if r["offset"] != 0.3)


def test_fit_writes_the_final_offset_and_the_final_maps_reliability():
    samples = _samples(0.25)
    res = fit(samples)
    assert res["calib_offset"] == res["final_offset"]["offset"]
    assert abs(res["calib_offset"] - 0.25) < 1e-9              # searched within z0 +- 1 (z's own best, near 0)
    assert res["calib_scale"] > 0                              # a higher z (more static) is less dynamic
    rel = res["reliability"]
    # reliability of the final maps at the chosen offset: its 0.95 pixels are the movers, its 0.05 static
    assert rel[9]["moving_share"] == 1.0 and rel[0]["moving_share"] == 0.0
    assert all(r["pixels"] == 0 for r in rel[1:9])
