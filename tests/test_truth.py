"""Evaluation against the renderer's truth: depth, rebuilt cameras, and the F precision measure."""

import json
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from conftest import SAMPLE_SETS
from crowdcam.scenegen import SETS, Camera, _rot_axis, render_depth, scene_and_cameras, write_set
from crowdcam.truth import NoTruth, epipolar_errors, f_precision, load_cameras, static_points, true_F
from pipeline.loading import load_set
from pipeline.support import HOMOGRAPHY, OK

MAX_SIDE = 160           # below the rendered size: working coordinates differ from the originals


@pytest.fixture(scope="module")
def small_set(tmp_path_factory):
    """square_people at 30 % size (8 photos, about 190 x 145 px), loaded at max side 160."""
    root = tmp_path_factory.mktemp("truth") / "square_people"
    write_set(SETS["square_people"], root, scale=0.3)
    ps = load_set(root, MAX_SIDE)
    _, cams = load_cameras(root)
    X = static_points(root, [p.stem for p in ps.photos])
    return ps, cams, X


def _rotated(cam: Camera, degrees: float) -> Camera:
    """The camera turned by `degrees` about an oblique axis through its centre."""
    return Camera(cam.K, cam.R @ _rot_axis([1.0, 1.0, 0.3], np.radians(degrees)), cam.C, cam.size)


def test_scene_and_cameras_equal_the_bundled_cameras_json():
    meta = json.loads((SAMPLE_SETS / "low_collinear" / "cameras.json").read_text())
    _, cams, times = scene_and_cameras("low_collinear")
    assert len(cams) == len(meta["cameras"])
    for cam, t, m in zip(cams, times, meta["cameras"]):
        for k in ("K", "R", "C"):
            # JSON float repr and BLAS builds differ in the last bit, nothing more
            np.testing.assert_allclose(getattr(cam, k), np.array(m[k]), rtol=0, atol=1e-9)
        assert list(cam.size) == m["size"] and t == pytest.approx(m["time_s"], abs=1e-12)


def test_scene_and_cameras_at_a_scale_equal_that_sets_cameras_json(small_set):
    ps, cams_json, _ = small_set
    _, cams, _ = scene_and_cameras("square_people", scale=0.3)
    for k, cam in enumerate(cams):
        ref = cams_json[f"cam{k:02d}"]
        np.testing.assert_allclose(cam.K, ref.K, atol=1e-9)
        assert cam.size == ref.size


def test_render_depth_sees_ground_and_the_movers_of_the_ground_truth(small_set):
    ps, cams, X = small_set
    scene_at, _, times = scene_and_cameras("square_people", scale=0.3)
    stem = ps.photos[0].stem
    depth, moving = render_depth(scene_at(times[0]), cams[stem])
    assert depth.shape == moving.shape == cams[stem].size and depth.dtype == np.float32
    assert np.all(depth[np.isfinite(depth)] > 0)
    gt = cv2.imread(str(ps.root / "gt" / f"{stem}.png"), cv2.IMREAD_GRAYSCALE)
    assert (gt == 255).any()
    assert np.mean(moving[gt == 255]) > 0.99 and not moving[gt == 0].any()
    # static points lie on the scene: none below the ground, a good share on it
    Z = np.concatenate(list(X.values()))[:, 2]
    assert Z.min() > -1e-6 and np.mean(np.abs(Z) < 1e-6) > 0.2


def test_true_F_has_no_error(small_set):
    ps, cams, X = small_set
    assert ps.photos[0].scale < 1
    n = 0
    for a in ps.photos:
        for b in ps.photos:
            if a is b:
                continue
            F = true_F(cams[a.stem], cams[b.stem], a.scale, b.scale)
            err = epipolar_errors(F, a, b, cams[a.stem], cams[b.stem], X[a.stem])
            n += len(err)
            assert len(err) == 0 or err.max() < 0.05
    assert n > 10000


def test_an_F_from_a_camera_turned_by_one_degree_has_a_large_error(small_set):
    ps, cams, X = small_set
    a, b = ps.photos[0], ps.photos[2]
    F = true_F(cams[a.stem], _rotated(cams[b.stem], 1.0), a.scale, b.scale)
    err = epipolar_errors(F, a, b, cams[a.stem], cams[b.stem], X[a.stem])
    # 1 degree is about f / 57 = 2.6 px at this size; the part across the lines counts (1.8 px)
    assert len(err) > 300 and np.median(err) > 1.0 and np.percentile(err, 90) > 1.5


def _fake_result(ps, cams, bad: tuple[int, int]):
    """A SetResult stand-in: every ordered pair admitted with the true F, except `bad` (support
    turned by 3 degrees) and (0, 2), a homography pair (skipped by f_precision)."""
    n = len(ps.photos)
    pairs = {}
    for i in range(n):
        for j in range(n):
            if i != j:
                a, b = ps.photos[i], ps.photos[j]
                cb = _rotated(cams[b.stem], 3.0) if (i, j) == bad else cams[b.stem]
                pairs[(i, j)] = SimpleNamespace(status=OK, F=true_F(cams[a.stem], cb, a.scale, b.scale),
                                                source="reconstruction" if (i, j) == bad else "two-view",
                                                uncertainty_px=float("nan") if (i, j) == bad else 0.5)
    pairs[(0, 2)] = SimpleNamespace(status=HOMOGRAPHY, F=pairs[(0, 2)].F, source="homography", uncertainty_px=1.0)
    supports = [[j for j in range(n) if j != i] for i in range(n)]
    return SimpleNamespace(photo_set=ps, pairs=pairs, supports=supports)


def test_f_precision_summarises_the_admitted_epipolar_pairs(small_set):
    ps, cams, _ = small_set
    fp = f_precision(_fake_result(ps, cams, bad=(1, 3)))
    n = len(ps.photos)
    assert fp["n_pairs"] == n * (n - 1) - 1            # the homography pair is not measured
    rows = {(r["ref"], r["sup"]): r for r in fp["pairs"]}
    assert ("cam00", "cam02") not in rows
    assert rows[("cam01", "cam03")]["p90_px"] > 2.0
    good = [r for k, r in rows.items() if k != ("cam01", "cam03") and r["n_points"]]
    assert max(r["p90_px"] for r in good) < 0.05
    assert fp["median_of_medians_px"] < 0.05
    assert fp["share_median_below_2px"] >= (fp["n_measured"] - 1) / fp["n_measured"]
    # each row names its geometry's source; the figures per source find the wrong pair's kind
    assert rows[("cam01", "cam03")]["source"] == "reconstruction"
    assert rows[("cam01", "cam03")]["uncertainty_px"] is None          # NaN is not JSON
    assert set(fp["by_source"]) == {"reconstruction", "two-view"}
    assert fp["by_source"]["two-view"]["n_measured"] == fp["n_measured"] - 1
    assert fp["by_source"]["two-view"]["median_of_medians_px"] < 0.05
    assert fp["by_source"]["reconstruction"]["n_measured"] == 1
    json.dumps(fp, allow_nan=False)


def test_no_truth_for_real_photos_or_unknown_sets(small_set, tmp_path):
    ps, _, _ = small_set
    real = tmp_path / "real"
    (real / "images").mkdir(parents=True)
    for p in ps.photos[:2]:
        (real / "images" / p.path.name).write_bytes(p.path.read_bytes())
    rps = load_set(real, MAX_SIDE)
    assert f_precision(SimpleNamespace(photo_set=rps, pairs={}, supports=[[], []])) is None
    with pytest.raises(NoTruth, match="no cameras.json"):
        static_points(real, ["cam00"])
    meta = json.loads((ps.root / "cameras.json").read_text())
    (real / "cameras.json").write_text(json.dumps({**meta, "name": "holiday"}))
    with pytest.raises(NoTruth, match="'holiday' is not one of the generator's sets"):
        static_points(real, ["cam00"])


def test_bench_cell_without_truth_is_a_dash():
    from crowdcam.bench import _f_cell
    assert _f_cell(None) == "–"
    assert _f_cell({"n_measured": 4, "share_median_below_2px": 0.75, "n_p90_above_10px": 1,
                    "median_of_medians_px": 0.8}) == "75%/1/0.80"
