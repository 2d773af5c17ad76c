"""The set's cameras from one reconstruction (pipeline/reconstruction.py): known answers on a small
rendered set, the two-view fallback for a photo that cannot register, the COLMAP export read back."""

import dataclasses
import json
import shutil

import numpy as np
import pytest

from conftest import SAMPLE_SETS


@pytest.fixture(scope="module")
def recon_run(tmp_path_factory):
    """tabletop_ball at 320 px with the default preset: geometry only (no pairs matched)."""
    from pipeline.cache import PairCache
    from pipeline.loading import load_set
    from pipeline.params import get_preset
    from pipeline.run import detect_set
    ps = load_set(SAMPLE_SETS / "tabletop_ball", 320)
    res = detect_set(ps, get_preset("default").replace(max_side=320), PairCache(None), workers=1, only_refs=[])
    return ps, res


def assert_cameras_match_the_truth(ps, res) -> None:
    """At least five cameras, every focal length within 3 % of the truth, and the issue's precision
    target on at least 8 reconstruction pairs (>= 95 % under 2 px median, none over 10 px p90)."""
    from crowdcam.truth import f_precision, load_cameras
    cams = res.cameras
    assert cams.n_registered >= 5
    _, truth = load_cameras(ps.root)
    for k in np.nonzero(cams.registered)[0]:
        p = ps.photos[k]
        f_true = truth[p.stem].K[0, 0] * p.scale
        assert abs(cams.K[k][0, 0] / f_true - 1) < 0.03            # focal length within 3 %
    index = {p.stem: k for k, p in enumerate(ps.photos)}
    recon = [r for r in f_precision(res)["pairs"] if res.pairs[(index[r["ref"]], index[r["sup"]])].source == "reconstruction"]
    assert len(recon) >= 8
    assert np.mean([r["median_px"] < 2.0 for r in recon]) >= 0.95      # the precision target
    assert all(r["p90_px"] < 10.0 for r in recon)


def test_cameras_match_the_truth(recon_run):
    assert_cameras_match_the_truth(*recon_run)


def test_pairs_say_where_their_geometry_comes_from(recon_run):
    ps, res = recon_run
    for (i, j), g in res.pairs.items():
        assert g.source in ("reconstruction", "two-view", "homography", "")
        assert (g.source == "") == (not g.ok)
        if g.source == "reconstruction":
            assert res.cameras.registered[i] and res.cameras.registered[j]
            assert np.isfinite(g.uncertainty_px) and g.uncertainty_px >= 0
            # F from the cameras, in the x_sup^T F x_ref = 0 convention
            np.testing.assert_allclose(np.abs(g.F), np.abs(res.cameras.F(i, j)), atol=1e-9)


def test_a_photo_that_cannot_register_falls_back_to_two_view(tmp_path):
    """A photo of something else (noise) joins the set: it gets no camera, a reason, and the
    others keep theirs; the run still works."""
    import cv2

    from pipeline.cache import PairCache
    from pipeline.loading import load_set
    from pipeline.params import get_preset
    from pipeline.run import detect_set
    root = tmp_path / "set"
    shutil.copytree(SAMPLE_SETS / "tabletop_ball" / "images", root)
    rng = np.random.default_rng(0)
    cv2.imwrite(str(root / "zz_other.png"), rng.integers(0, 255, (300, 400, 3), dtype=np.uint8))
    ps = load_set(root, 320)
    warnings = []
    res = detect_set(ps, get_preset("default").replace(max_side=320), PairCache(None), workers=1, only_refs=[],
                     warn=warnings.append)
    k = [p.stem for p in ps.photos].index("zz_other")
    assert not res.cameras.registered[k] and res.cameras.reasons[k]
    assert res.cameras.n_registered >= 5
    assert any("zz_other" in w and "two-view" in w for w in warnings)
    assert all(not res.pairs[(k, j)].ok for j in range(len(ps.photos)) if j != k)


def test_three_cameras_are_not_enough_to_be_trusted(tmp_path):
    """A model of three cameras cannot check itself (each camera answers to two others only): a set
    of three photos that reconstructs keeps two-view geometry for every pair, with the reason said."""
    from pipeline.cache import PairCache
    from pipeline.loading import load_set
    from pipeline.params import get_preset
    from pipeline.run import detect_set
    root = tmp_path / "three"
    root.mkdir()
    for f in sorted((SAMPLE_SETS / "tabletop_ball" / "images").iterdir())[:3]:
        shutil.copy(f, root / f.name)
    ps = load_set(root, 320)
    params = get_preset("default").replace(max_side=320)
    warnings = []
    res = detect_set(ps, params, PairCache(None), workers=1, only_refs=[], warn=warnings.append)
    assert res.cameras.n_registered == 0
    assert all("fewer than 4 photos" in r or "not registered" in r for r in res.cameras.reasons)
    assert any("no reconstruction of the set" in w for w in warnings)
    admitted = [g for g in res.pairs.values() if g.ok]
    assert admitted and all(g.source in ("two-view", "homography") for g in admitted)
    # the rule is the setting's: with three allowed, the same photos do get their cameras
    three = params.replace(geometry=dataclasses.replace(params.geometry, recon_min_registered=3))
    res3 = detect_set(ps, three, PairCache(None), workers=1, only_refs=[])
    assert res3.cameras.n_registered == 3


def test_two_view_geometry_does_not_depend_on_the_initial_focal_length(recon_run):
    """Both mapping runs read one set of COLMAP two-view geometries (made once, not once per run):
    sound because they are the same from either run's initial focal length, with or without an
    EXIF prior on one photo of a pair."""
    from pipeline.params import get_preset
    from pipeline.reconstruction import _input_pairs, two_view_task
    ps, res = recon_run
    n = len(ps.photos)
    p = get_preset("default").geometry
    links = _input_pairs(res.pairs, n, p.recon_min_matches)
    assert len(links) >= 6
    sizes = [ph.size for ph in ps.photos]
    for prior in (np.full(n, np.nan), np.r_[1.1 * max(sizes[0]), np.full(n - 1, np.nan)]):
        a, b = (two_view_task(res.keypoints, sizes, links, prior, guess) for guess in p.recon_focal_guesses)
        for ga, gb in zip(a, b):
            assert ga.config == gb.config and np.array_equal(ga.inlier_matches, gb.inlier_matches)
            assert (ga.cam2_from_cam1 is None) == (gb.cam2_from_cam1 is None)
            if ga.cam2_from_cam1 is not None:
                assert np.array_equal(ga.cam2_from_cam1.matrix(), gb.cam2_from_cam1.matrix())
        assert sum(len(g.inlier_matches) > 0 for g in a) >= 6


def test_a_failed_mapping_says_nothing_on_the_terminal(capfd, monkeypatch):
    """Matches from which no model can be made: _map returns no model, and COLMAP's own log line
    ("Failed to create any sparse model", written by its C++ code to the process's stderr) does not
    reach the user; run.py says it in one line of ours."""
    from pipeline.params import get_preset
    from pipeline.reconstruction import _map, two_view_task
    monkeypatch.delenv("CROWDCAM_COLMAP_LOG", raising=False)
    rng = np.random.default_rng(0)
    keypoints = [rng.uniform(0, 300, (200, 2)).astype(np.float32) for _ in range(4)]
    links = [(i, j, np.column_stack([np.arange(100), rng.permutation(200)[:100]]), False)
             for i in range(4) for j in range(i + 1, 4)]
    sizes, prior = [(240, 320)] * 4, np.full(4, np.nan)
    two_view = two_view_task(keypoints, sizes, links, prior, 1.0)
    rec, _, n_models = _map(keypoints, sizes, links, two_view, get_preset("default").geometry, prior, 1.0)
    assert rec is None and n_models == 0
    err = capfd.readouterr().err
    assert "sparse model" not in err and err.strip() == ""


def test_colmap_export_reads_back(recon_run, tmp_path):
    import pycolmap

    from pipeline.reconstruction import export_colmap_text
    ps, res = recon_run
    cams = res.cameras
    export_colmap_text(cams, ps.photos, res.keypoints, tmp_path)
    rec = pycolmap.Reconstruction()
    rec.read_text(str(tmp_path))
    assert rec.num_reg_images() == cams.n_registered
    assert rec.num_points3D() == len(np.unique(cams.obs[np.isin(cams.obs[:, 1], np.nonzero(cams.registered)[0]), 0]))
    by_name = {im.name: im for im in rec.images.values()}
    for k in np.nonzero(cams.registered)[0]:
        p = ps.photos[k]
        im = by_name[p.name]
        assert (im.camera.width, im.camera.height) == (p.orig_size[1], p.orig_size[0])
        # a sparse point it sees projects where the photo's keypoint is, at the original size
        pid = int(cams.obs[cams.obs[:, 1] == k][0, 0])
        kp = int(cams.obs[(cams.obs[:, 1] == k) & (cams.obs[:, 0] == pid)][0, 2])
        xy = np.asarray(im.project_point(rec.point3D(pid + 1).xyz)) - 0.5      # COLMAP: +0.5 pixel centres
        want = (res.keypoints[k][kp] + 0.5) / p.scale - 0.5
        assert np.linalg.norm(xy - want) < 2.0 / p.scale


def test_summary_has_cameras_and_pair_sources(recon_run, tmp_path):
    from pipeline.output import summary_dict
    ps, res = recon_run
    d = json.loads(json.dumps(summary_dict(res, 0.5)))
    reg = [im for im in d["images"] if im["camera"] is not None]
    assert len(reg) == res.cameras.n_registered
    assert np.asarray(reg[0]["camera"]["K"]).shape == (3, 3)
    assert {p["source"] for p in d["pairs"]} <= {"reconstruction", "two-view", "homography", "rejected"}
    assert any(p["source"] == "reconstruction" and p["uncertainty_px"] is not None for p in d["pairs"])


def test_paper_preset_keeps_two_view_geometry():
    from pipeline.params import get_preset
    assert not get_preset("paper").geometry.reconstruction
    assert get_preset("default").geometry.reconstruction


def test_exif_focal_prior(tmp_path):
    """A 35 mm-equivalent focal length in EXIF becomes a prior in working pixels; absurd values
    are ignored with a warning."""
    from PIL import Image

    from pipeline.loading import FULL_FRAME_DIAGONAL_MM, load_photo
    for value, expect in ((28, True), (0, False), (5000, False)):
        path = tmp_path / f"f{value}.jpg"
        exif = Image.Exif()
        exif.get_ifd(0x8769)[0xA405] = value
        Image.fromarray(np.full((300, 400, 3), 128, np.uint8)).save(path, exif=exif)
        warned = []
        ph = load_photo(path, 200, warned.append)
        if expect:
            assert ph.focal_prior_px == pytest.approx(value / FULL_FRAME_DIAGONAL_MM * np.hypot(150, 200))
            assert not warned
        else:
            assert ph.focal_prior_px is None and warned and "ignored" in warned[0]


def test_a_planar_pair_is_rescued_only_when_the_setting_says_so(recon_run):
    """A pair the two-view tests rejected because one homography explains its matches: the
    cameras' F takes it in by default; with recon_rescue_planar off it stays rejected, saying why."""
    from pipeline.params import get_preset
    from pipeline.reconstruction import apply_reconstruction
    from pipeline.support import REJECTED
    ps, res = recon_run
    i, j = next((i, j) for (i, j), g in sorted(res.pairs.items()) if i < j and g.source == "reconstruction")
    planar = dataclasses.replace(res.pairs[(i, j)], status=REJECTED, source="", homography_share=0.95,
                                 reason="degenerate F, and residual parallax after the homography is 9.0 px")
    pairs = dict(res.pairs)
    pairs[(i, j)], pairs[(j, i)] = planar, planar.reversed()
    sizes = [p.size for p in ps.photos]
    geometry = get_preset("default").geometry
    rescued = apply_reconstruction(pairs, res.cameras, sizes, res.keypoints, geometry)
    assert rescued[(i, j)].source == "reconstruction" and rescued[(j, i)].ok
    kept = apply_reconstruction(pairs, res.cameras, sizes, res.keypoints,
                                dataclasses.replace(geometry, recon_rescue_planar=False))
    assert not kept[(i, j)].ok and not kept[(j, i)].ok
    assert "on one plane" in kept[(i, j)].reason and "degenerate F" in kept[(i, j)].reason
    # pairs that passed their own tests are not touched by the setting
    assert all(kept[ij].source == rescued[ij].source for ij in pairs if ij not in ((i, j), (j, i)))


def test_uncertain_camera_lines_replace_a_two_view_f_only_where_they_fit_its_matches(recon_run):
    """A pair of registered photos whose cameras' lines are uncertain by the estimate (above
    recon_max_uncertainty_frac) but whose own two-view F passed: the cameras' F is taken where it
    fits the pair's matches and the two-view lines are certain themselves; the pair is then not
    swept (uncertain lines). Elsewhere, and with the setting off, the two-view F stays."""
    from pipeline.params import get_preset
    from pipeline.reconstruction import apply_reconstruction
    from pipeline.run import _sweepable
    from pipeline.support import OK
    ps, res = recon_run
    i, j = next((i, j) for (i, j), g in sorted(res.pairs.items()) if i < j and g.source == "reconstruction")
    sizes = [p.size for p in ps.photos]
    params = get_preset("default").replace(max_side=320)
    geometry = params.geometry
    unc = np.array(res.cameras.pair_unc)
    unc[i, j] = unc[j, i] = 3 * geometry.recon_max_uncertainty_frac * max(sizes[i])
    cams = dataclasses.replace(res.cameras, pair_unc=unc)

    def with_pair(g):
        pairs = dict(res.pairs)
        pairs[(i, j)], pairs[(j, i)] = g, g.reversed()
        return pairs
    two_view = dataclasses.replace(res.pairs[(i, j)], status=OK, source="two-view", uncertainty_px=2.0)
    taken = apply_reconstruction(with_pair(two_view), cams, sizes, res.keypoints, geometry)[(i, j)]
    assert taken.source == "reconstruction" and taken.ok and taken.uncertainty_px == unc[i, j]
    assert np.allclose(taken.F, cams.F(i, j))
    assert not _sweepable((i, j), taken, cams, params, sizes[i])
    assert _sweepable((i, j), res.pairs[(i, j)], res.cameras, params, sizes[i])     # certain lines: swept
    off = apply_reconstruction(with_pair(two_view), cams, sizes, res.keypoints,
                               dataclasses.replace(geometry, recon_over_two_view=False))[(i, j)]
    assert off.source == "two-view" and np.array_equal(off.F, two_view.F)
    loose = dataclasses.replace(two_view, uncertainty_px=1.1 * geometry.two_view_max_uncertainty_frac * max(sizes[i]))
    assert apply_reconstruction(with_pair(loose), cams, sizes, res.keypoints, geometry)[(i, j)].source == "two-view"
    # matches 6 px off the cameras' lines (each support point moved along its epipolar line's normal)
    lines = cams.F(i, j) @ np.column_stack([two_view.inliers_ref, np.ones(len(two_view.inliers_ref))]).T
    normal = (lines[:2] / np.linalg.norm(lines[:2], axis=0)).T
    off_lines = dataclasses.replace(two_view, inliers_sup=(two_view.inliers_sup + 6.0 * normal).astype(np.float32))
    assert apply_reconstruction(with_pair(off_lines), cams, sizes, res.keypoints, geometry)[(i, j)].source == "two-view"


@pytest.mark.parametrize("scale", [1e-5, 1e-30])
def test_line_uncertainty_is_the_spread_of_lines_of_poses_drawn_from_the_covariance(scale):
    """line_uncertainty (poses drawn at once, lines in one compiled pass) equals drawing the poses
    one at a time with numpy and OpenCV's Rodrigues; at 1e-30 the rotations are below the compiled
    pass's first-order threshold."""
    import cv2

    from pipeline.reconstruction import line_uncertainty
    rng = np.random.default_rng(2)
    K = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])
    A = rng.normal(size=(6, 6))
    cov = A @ A.T * scale
    R, _ = cv2.Rodrigues(np.array([0.1, -0.2, 0.05]))
    t = np.array([1.0, 0.1, 0.2])
    x, y = rng.uniform(0, 600, (60, 2)), rng.uniform(0, 400, (60, 2))

    def skew(v):
        return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])

    draws = np.random.default_rng(7)
    L = np.linalg.cholesky(cov + 1e-18 * np.eye(6))
    d2 = np.zeros(len(x))
    for _ in range(32):
        dlt = L @ draws.standard_normal(6)
        F = np.linalg.inv(K).T @ skew(t + dlt[3:]) @ cv2.Rodrigues(dlt[:3])[0] @ R @ np.linalg.inv(K)
        lines = np.column_stack([x, np.ones(len(x))]) @ F.T
        d = (np.sum(lines[:, :2] * y, axis=1) + lines[:, 2]) / np.linalg.norm(lines[:, :2], axis=1)
        d2 += d * d
    want = np.percentile(np.sqrt(d2 / 32), 90)
    assert line_uncertainty(K, K, R, t, cov, x, y, samples=32, seed=7) == pytest.approx(want, rel=1e-9)


def test_the_mapping_runs_in_worker_processes_give_the_cameras_made_here(recon_run):
    """The two mapping runs go to the worker pool side by side; their models come back as COLMAP's
    binary files, so the cameras, points and uncertainties are the ones a run here makes, bit for bit."""
    from pipeline.cache import PairCache
    from pipeline.params import get_preset
    from pipeline.run import detect_set
    ps, res = recon_run
    pooled = detect_set(ps, get_preset("default").replace(max_side=320), PairCache(None), workers=2,
                        only_refs=[]).cameras
    for f in dataclasses.fields(pooled):
        if f.name == "seconds":
            continue
        a, b = getattr(res.cameras, f.name), getattr(pooled, f.name)
        if isinstance(a, np.ndarray):
            assert a.shape == b.shape and np.array_equal(a, b, equal_nan=True), f.name
        else:
            assert a == b, f.name


def test_large_sets_get_lighter_bundle_adjustments_and_the_cameras_stay_right(recon_run, monkeypatch):
    """Above `recon_light_ba_above` photos the mapper's global bundle adjustments leave out redundant
    points and the robust refinement stops at Ceres' function tolerance (the cost of a hundred
    photos); below it COLMAP's settings. Made to apply to this small set, the lighter adjustments
    still recover the true cameras."""
    import pycolmap

    from pipeline.cache import PairCache
    from pipeline.params import get_preset
    from pipeline.run import detect_set
    ps, _ = recon_run
    seen, tolerances = [], []
    real, real_adjuster = pycolmap.incremental_mapping, pycolmap.create_default_bundle_adjuster

    def spy(db, images, out, opts):
        seen.append(opts.mapper.ba_global_ignore_redundant_points3D)
        return real(db, images, out, opts)

    def spy_adjuster(opts, config, rec):
        tolerances.append(opts.ceres.solver_options.function_tolerance)
        return real_adjuster(opts, config, rec)
    monkeypatch.setattr(pycolmap, "incremental_mapping", spy)
    monkeypatch.setattr(pycolmap, "create_default_bundle_adjuster", spy_adjuster)
    params = get_preset("default").replace(max_side=320)
    assert len(ps.photos) <= params.geometry.recon_light_ba_above
    fast = params.replace(geometry=dataclasses.replace(params.geometry, recon_light_ba_above=len(ps.photos) - 1))
    res_fast = detect_set(ps, fast, PairCache(None), workers=1, only_refs=[])
    assert seen == [True, True]                                        # both runs
    assert tolerances and set(tolerances) == {1e-6}
    seen.clear()
    tolerances.clear()
    detect_set(ps, params, PairCache(None), workers=1, only_refs=[])
    assert seen == [False, False]                                      # COLMAP's default
    assert tolerances and set(tolerances) == {0.0}
    assert_cameras_match_the_truth(ps, res_fast)


def test_the_ground_is_found_among_many_points_without_an_n_by_n_temporary():
    """ground_plane finds the plane that holds most sparse points, its normal pointing to the
    cameras above it; on 20 000 points its refit allocates little (the full SVD's (N, N) left
    factor was 3.2 GB here, 1.2 GB on a hundred photos' points)."""
    import tracemalloc

    from pipeline.reconstruction import SetCameras, ground_plane
    rng = np.random.default_rng(0)
    n_ground, n_other = 15_000, 5_000
    ground = np.column_stack([rng.uniform(-20, 20, n_ground), np.full(n_ground, 1.5), rng.uniform(5, 40, n_ground)])
    other = rng.uniform([-20, -10, 5], [20, 1.0, 40], (n_other, 3))         # above the ground (y points down)
    tilt = np.deg2rad(5.0)                                                  # a world turned about x
    Rw = np.array([[1, 0, 0], [0, np.cos(tilt), -np.sin(tilt)], [0, np.sin(tilt), np.cos(tilt)]])
    X = np.vstack([ground, other]) @ Rw.T
    n_cams = 4
    R = np.repeat(Rw.T[None], n_cams, axis=0)                                # cameras level with the old world
    C = np.column_stack([np.linspace(-3, 3, n_cams), np.zeros(n_cams), np.zeros(n_cams)]) @ Rw.T
    cams = SetCameras(np.ones(n_cams, bool), np.repeat(np.eye(3)[None], n_cams, 0), R, C,
                      np.full((n_cams, 2), np.nan), X, np.zeros(len(X), np.float32), np.zeros((len(X), 3), np.uint8),
                      np.zeros((0, 3), np.int32), np.full((n_cams, n_cams), np.nan), ("",) * n_cams,
                      np.full(n_cams, np.nan), 0.0, 0.0)
    tracemalloc.start()
    found = ground_plane(cams)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert found is not None
    normal, d = found
    up = Rw @ np.array([0.0, -1.0, 0.0])                                     # towards the cameras
    assert np.degrees(np.arccos(np.clip(normal @ up, -1, 1))) < 0.5
    assert np.all(C @ normal + d > 0)                                       # the cameras are above it
    np.testing.assert_allclose(np.abs(ground @ Rw.T @ normal + d).max(), 0.0, atol=1e-6)
    assert peak < 50e6
