"""Evaluation against the renderer's truth: how right are the fundamental matrices of a run?

Not part of the pipeline. For the synthetic sets of crowdcam/scenegen.py, the scene and the
cameras are known exactly: `cameras.json` holds every camera (K at the rendered size,
x = K R (X - C), pixel (0, 0) the centre of the top-left pixel) and the set is rebuilt
deterministically from SETS[name]. Static surface points seen by a photo come from the
renderer's depth; their true projections into another photo must lie on the epipolar lines of a
right F. `f_precision` measures, for every admitted epipolar pair of a run, how far they lie
from them, in working pixels of the support.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from crowdcam.scenegen import SETS, Camera, render_depth, scene_and_cameras
from pipeline.geometry import epipolar_lines, fundamental_from_cameras, scale_matrix, to_homogeneous
from pipeline.support import OK

GOOD_MEDIAN_PX = 2.0      # a pair whose median error is below this has a right F
BAD_P90_PX = 10.0         # a pair whose 90th percentile is above this misleads a good share of its strips


class NoTruth(ValueError):
    """The set has a cameras.json that cannot be traced back to the generator."""


def load_cameras(set_root: Path) -> tuple[dict, dict[str, Camera]] | None:
    """(cameras.json as a dict, stem -> Camera at the rendered size), or None without cameras.json."""
    path = Path(set_root) / "cameras.json"
    if not path.is_file():
        return None
    meta = json.loads(path.read_text())
    cams = {c["stem"]: Camera(np.array(c["K"], float), np.array(c["R"], float), np.array(c["C"], float),
                              tuple(c["size"])) for c in meta.get("cameras", [])}
    return meta, cams


def _scene_at(meta: dict, set_root: Path):
    """The set's scene as a function of time, rebuilt from SETS; NoTruth when it cannot be."""
    name = meta.get("name")
    if name not in SETS:
        raise NoTruth(f"{set_root}/cameras.json: set {name!r} is not one of the generator's sets "
                      f"({', '.join(SETS)}); its scene cannot be rebuilt")
    if meta.get("seed") != SETS[name].seed:
        raise NoTruth(f"{set_root}/cameras.json: seed {meta.get('seed')} differs from the generator's "
                      f"{SETS[name].seed} for {name!r}; re-render the set")
    return scene_and_cameras(name)[0]


def static_points(set_root: Path, stems: list[str], step: int = 4) -> dict[str, np.ndarray]:
    """World points of the static surfaces each photo sees, on a pixel grid every `step` px.

    Returns stem -> (N, 3) float64 (sky and pixels whose first hit is a mover excluded), for the
    stems that cameras.json knows. Raises NoTruth when the set has no cameras.json or is not a
    set of the generator.
    """
    set_root = Path(set_root)
    loaded = load_cameras(set_root)
    if loaded is None:
        raise NoTruth(f"{set_root}: no cameras.json (not a synthetic set); no true cameras to compare with")
    meta, cams = loaded
    scene_at = _scene_at(meta, set_root)
    times = {c["stem"]: float(c["time_s"]) for c in meta["cameras"]}
    out = {}
    for stem in stems:
        if stem not in cams:
            continue
        cam = cams[stem]
        depth, moving = render_depth(scene_at(times[stem]), cam)
        # Pixel centres on the grid; the renderer casts its rays through the same centres.
        z = depth[::step, ::step].astype(np.float64)
        keep = np.isfinite(z) & ~moving[::step, ::step]
        ys, xs = np.mgrid[0:cam.size[0]:step, 0:cam.size[1]:step]
        pix = np.stack([xs[keep], ys[keep], np.ones(int(keep.sum()))], axis=1).astype(np.float64)
        # x_cam = z K^-1 (u, v, 1), X = C + R^T x_cam
        out[stem] = cam.C + (z[keep][:, None] * (pix @ np.linalg.inv(cam.K).T)) @ cam.R
    return out


def _project(cam: Camera, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) world points -> (N, 2) float64 original pixels and (N,) float64 camera-frame z."""
    xc = (X - cam.C) @ cam.R.T
    x = xc @ cam.K.T
    with np.errstate(divide="ignore", invalid="ignore"):
        return x[:, :2] / x[:, 2:3], xc[:, 2]


def _to_work(pts: np.ndarray, scale: float) -> np.ndarray:
    """(N, 2) original pixels -> working pixels of a photo resized by `scale` (geometry.scale_matrix)."""
    return pts * scale + (0.5 * scale - 0.5)


def epipolar_errors(F_work: np.ndarray, photo_i, photo_j, cam_i: Camera, cam_j: Camera,
                    X_i: np.ndarray) -> np.ndarray:
    """Distances (K,) float64, in working pixels of support j, of the true matches to F's lines.

    F_work: (3, 3) with x_sup^T F x_ref = 0 in working coordinates of photo_i (reference) and
    photo_j (support) (pipeline.loading.Photo: .scale, .orig_size). X_i: (N, 3) static points seen
    by photo i; the K of them in front of camera j that project inside photo j are measured.
    """
    x_i, _ = _project(cam_i, X_i)
    x_j, z_j = _project(cam_j, X_i)
    h, w = cam_j.size
    inside = (z_j > 1e-6) & (x_j[:, 0] >= -0.5) & (x_j[:, 0] < w - 0.5) & (x_j[:, 1] >= -0.5) & (x_j[:, 1] < h - 0.5)
    lines = epipolar_lines(F_work, _to_work(x_i[inside], photo_i.scale))
    return np.abs(np.sum(to_homogeneous(_to_work(x_j[inside], photo_j.scale)) * lines, axis=1))


def true_F(cam_i: Camera, cam_j: Camera, scale_i: float, scale_j: float) -> np.ndarray:
    """The true F (3, 3) float64, unit norm, x_j^T F x_i = 0 in working coordinates of photos
    resized by scale_i and scale_j (the cameras' K are at the rendered size)."""
    return fundamental_from_cameras(scale_matrix(scale_i) @ cam_i.P, scale_matrix(scale_j) @ cam_j.P)


def _pair_row(ref: str, sup: str, err: np.ndarray) -> dict:
    if len(err) == 0:       # no static point of the reference falls inside the support
        return {"ref": ref, "sup": sup, "n_points": 0, "median_px": None, "p90_px": None}
    med, p90 = np.percentile(err, [50, 90])
    return {"ref": ref, "sup": sup, "n_points": int(len(err)), "median_px": float(med), "p90_px": float(p90)}


def f_precision(result, step: int = 4) -> dict | None:
    """F precision of a run (pipeline.run.SetResult) against the true cameras.

    For every admitted epipolar ordered pair (ref i, support j; status "ok" with an F; homography
    pairs are skipped): the median and 90th percentile of epipolar_errors over the static points
    photo i sees. Returns {"pairs": [{"ref", "sup", "n_points", "median_px", "p90_px", "source",
    "uncertainty_px"}, ...], "n_pairs", "n_measured", "share_median_below_2px", "n_p90_above_10px",
    "median_of_medians_px", "by_source": {source: the same four figures over its pairs}} (shares
    over the measured pairs; None where nothing was measured), or None when the set has no
    cameras.json (real photos). Raises NoTruth when its cameras.json cannot be traced back to the
    generator or does not fit the photos.
    """
    ps = result.photo_set
    loaded = load_cameras(ps.root)
    if loaded is None:
        return None
    _, cams = loaded
    photos = ps.photos
    for p in photos:
        if p.stem in cams and tuple(cams[p.stem].size) != tuple(p.orig_size):
            raise NoTruth(f"{ps.root}/cameras.json: {p.stem} is {cams[p.stem].size} there but the photo is "
                          f"{p.orig_size}")
    pairs = [(i, j) for i, sup in enumerate(result.supports) for j in sup
             if result.pairs[(i, j)].status == OK and result.pairs[(i, j)].F is not None
             and photos[i].stem in cams and photos[j].stem in cams]
    refs = sorted({photos[i].stem for i, _ in pairs})
    X = static_points(ps.root, refs, step) if pairs else {}
    rows = []
    for i, j in pairs:
        a, b = photos[i], photos[j]
        g = result.pairs[(i, j)]
        err = epipolar_errors(g.F, a, b, cams[a.stem], cams[b.stem], X[a.stem])
        unc = float(g.uncertainty_px)
        rows.append(dict(_pair_row(a.stem, b.stem, err), source=g.source,
                         uncertainty_px=unc if np.isfinite(unc) else None))
    out = {"pairs": rows, "n_pairs": len(rows), **_shares(rows)}
    # which geometry the wrong pairs come from: what a researcher looks at first
    out["by_source"] = {src: _shares([r for r in rows if r["source"] == src])
                        for src in sorted({r["source"] for r in rows})}
    return out


def _shares(rows: list[dict]) -> dict:
    meds = np.array([r["median_px"] for r in rows if r["n_points"]], float)
    p90s = np.array([r["p90_px"] for r in rows if r["n_points"]], float)
    return {"n_measured": int(len(meds)),
            "share_median_below_2px": float(np.mean(meds < GOOD_MEDIAN_PX)) if len(meds) else None,
            "n_p90_above_10px": int(np.sum(p90s > BAD_P90_PX)),
            "median_of_medians_px": float(np.median(meds)) if len(meds) else None}
