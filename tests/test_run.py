"""Runs in one process (the inspector's inline runs, one worker)."""

import threading

import numpy as np
import pytest

from conftest import SAMPLE_SETS


def test_two_inline_runs_of_different_presets_at_once_equal_their_runs_alone(tmp_path):
    """A viewer may run a second preset while the first is going (one worker: both inline, in
    this process); each must use its own parameters (it once computed the other's pairs)."""
    from pipeline.cache import PairCache
    from pipeline.loading import load_set
    from pipeline.params import get_preset
    from pipeline.run import detect_set

    ps = load_set(SAMPLE_SETS / "tabletop_ball", 160)
    presets = ("paper", "peer-homography")
    alone = {name: detect_set(ps, get_preset(name).replace(max_side=160), PairCache(tmp_path / f"a-{name}"),
                              workers=1).dynamic for name in presets}
    together, errors = {}, []

    def run(name):
        try:
            together[name] = detect_set(ps, get_preset(name).replace(max_side=160), PairCache(tmp_path / f"b-{name}"),
                                        workers=1).dynamic
        except Exception as e:        # reported below, with the preset's name
            errors.append((name, repr(e)))
    threads = [threading.Thread(target=run, args=(name,)) for name in presets]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    for name in presets:
        for a, b in zip(alone[name], together[name]):
            assert (a is None and b is None) or np.array_equal(a, b)


def test_maps_made_in_threads_equal_maps_made_one_by_one(tmp_path):
    """The last stage makes the photos' maps `workers` at a time, in threads: the same maps as
    one by one, and one "maps" progress step per photo with a map."""
    from pipeline.cache import PairCache
    from pipeline.loading import load_set
    from pipeline.params import get_preset
    from pipeline.run import detect_set

    params = get_preset("default").replace(max_side=160)
    ps = load_set(SAMPLE_SETS / "tabletop_ball", params.max_side)
    one = detect_set(ps, params, PairCache(tmp_path / "one"), workers=1)
    steps = []
    two = detect_set(ps, params, PairCache(tmp_path / "two"), workers=2,
                     progress=lambda stage, done, total: steps.append((done, total)) if stage == "maps" else None)
    with_map = sum(1 for s in two.supports if s)
    assert with_map >= 2 and sorted(steps) == [(k, with_map) for k in range(1, with_map + 1)]
    for a, b in zip(one.dynamic, two.dynamic):
        assert (a is None) == (b is None)
        if a is not None:
            assert np.array_equal(a, b)


def test_default_pairs_carry_the_plane_difference_and_the_map_adds_it_last():
    """default: a pair holds its plane-aligned difference (where its matches give a homography), and the map is the one without the
    cue with the cue's log-odds added (after the guided filter); paper's pairs hold none."""
    import dataclasses

    from pipeline.cache import PairCache
    from pipeline.loading import load_set
    from pipeline.params import get_preset
    from pipeline.run import detect_set

    params = get_preset("default").replace(max_side=160)
    ps = load_set(SAMPLE_SETS / "tabletop_ball", params.max_side)
    res = detect_set(ps, params, PairCache(None), workers=1)
    diffs = {ij: r.plane_diff for ij, r in res.pair_results.items()}      # None: no homography of 40 matches
    assert all(d is None or d.shape == ps.photos[i].size for (i, _), d in diffs.items())
    i = next(k for k, s in enumerate(res.supports) if any(diffs[(k, j)] is not None for j in s))
    off = params.replace(aggregate=dataclasses.replace(params.aggregate, plane_weight=0.0))
    base = res.dynamic_prob(i, res.supports[i], off)
    z = res.plane_log_odds(i, res.supports[i])
    a = params.aggregate
    d = np.clip(base.astype(np.float64), 1e-6, 1 - 1e-6)
    want = 1 / (1 + np.exp(np.log((1 - d) / d) + a.plane_weight * np.maximum(z, -a.plane_dynamic_cap)))
    np.testing.assert_allclose(res.dynamic_prob(i, res.supports[i]), want, atol=1e-5)
    paper = get_preset("paper").replace(max_side=160)
    pres = detect_set(ps, paper, PairCache(None), workers=1)
    assert pres.pair_results and all(r.plane_diff is None for r in pres.pair_results.values())
    assert all(pres.plane_log_odds(k, s) is None for k, s in enumerate(pres.supports) if s)


def test_swept_supports_can_speak_through_the_depth_cue_alone():
    """aggregate.swept_strips = 0 leaves Eq. 3's strip term out for the supports that are swept: a
    photo whose supports are all swept then has the depth cue's log-odds alone; at 1 (default) the
    strips count too."""
    import dataclasses

    from pipeline.cache import PairCache
    from pipeline.loading import load_set
    from pipeline.params import get_preset
    from pipeline.run import detect_set

    params = get_preset("default").replace(max_side=240)           # (at 160 no pair is swept)
    ps = load_set(SAMPLE_SETS / "street_sideways", params.max_side)
    res = detect_set(ps, params, PairCache(None), workers=1)
    i = next(k for k, s in enumerate(res.supports) if s and all(res.is_swept(k, j) for j in s))
    off = params.replace(aggregate=dataclasses.replace(params.aggregate, swept_strips=0.0))
    depth_only = params.sweep.weight * res.sweep_log_odds(i, res.supports[i], off)
    np.testing.assert_allclose(res.static_log_odds(i, res.supports[i], off), depth_only, atol=1e-6)
    assert np.abs(res.static_log_odds(i, res.supports[i]) - depth_only).max() > 0.1


def test_swept_pairs_search_strips_of_their_own_fans():
    """patches.swept_fans: the strips of a pair that is also swept come in that many fans, the
    other pairs' in n_fans (the paper's three); 0 keeps n_fans for all."""
    from pipeline.cache import PairCache
    from pipeline.loading import load_set
    from pipeline.params import get_preset
    from pipeline.run import detect_set

    params = get_preset("default").replace(max_side=240)           # (at 160 no pair is swept)
    ps = load_set(SAMPLE_SETS / "street_sideways", params.max_side)
    res = detect_set(ps, params.with_settings(["patches.swept_fans=1"]), PairCache(None), workers=1)
    fans = {ij: res.pair_results[ij].strips.n_fans for ij in res.pair_results if res.kind(*ij) == "epipolar"}
    swept = {ij for ij in fans if res.is_swept(*ij)}
    assert swept and swept != set(fans)
    assert all(fans[ij] == (1 if ij in swept else 3) for ij in fans)


def test_geometry_tasks_read_the_shared_features_as_they_were_given():
    """A local pool's geometry tasks carry only two indices: the photos' features are written once
    into the pool's folder and read back there (run._Runner.share_features). Read back, they are
    the same features (responses unknown stay unknown), and a pair's geometry is the same bytes."""
    from pipeline import run
    from pipeline.features import Features
    from pipeline.loading import load_set
    from pipeline.params import get_preset

    params = get_preset("default").replace(max_side=200)
    ps = load_set(SAMPLE_SETS / "tabletop_ball", params.max_side)
    rgbs = [p.rgb for p in ps.photos]
    gp = params.geometry
    f0, f1 = (run.detect(rgbs[k], gp.sift_features, gp.sift_contrast) for k in (0, 1))
    f1 = Features(f1.xy, f1.size, f1.desc)                                   # responses unknown
    runner = run._Runner(rgbs, params, 2)
    saved = dict(run._W)
    try:
        assert runner.share_features({0: f0, 1: f1})
        run._init_worker_from_files(runner._folder, len(rgbs), params)       # as a pool worker starts
        g0, g1 = run._worker_features(0), run._worker_features(1)
        for a, b in ((f0, g0), (f1, g1)):
            for name in ("xy", "size", "desc"):
                np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
        np.testing.assert_array_equal(g0.response, f0.response)
        assert g1.response is None
        assert run._task_geometry(0, 1) == run._task_geometry(0, 1, f0, f1)
        assert not run._Runner(rgbs, params, 1).share_features({0: f0})     # inline: passed in the tasks
    finally:
        run._W.clear()
        run._W.update(saved)
        runner.close()


def test_a_set_smaller_than_the_working_size_runs_at_its_own_size(tmp_path):
    """Photos smaller than max_side are used as they are, and every length that follows the working
    size (the patch length, the guided filter's radius) follows the photos (Params.for_working_side):
    a set of 160-px photos gives the same maps under max_side 160 and 1280, from the same cache entries."""
    from pipeline.cache import PairCache
    from pipeline.loading import load_set
    from pipeline.params import get_preset
    from pipeline.run import detect_set

    small = load_set(SAMPLE_SETS / "tabletop_ball", 160)
    assert small.working_side == 160
    own = detect_set(small, get_preset("default").replace(max_side=160), PairCache(tmp_path / "own"), workers=1)
    big = detect_set(small, get_preset("default").replace(max_side=1280), PairCache(tmp_path / "big"), workers=1)
    assert big.params.max_side == 160
    assert sum(d is not None for d in own.dynamic) >= 2
    for a, b in zip(own.dynamic, big.dynamic):
        assert (a is None and b is None) or np.array_equal(a, b)
    # under the larger limit the run asks the cache for the very entries the first run wrote
    again = PairCache(tmp_path / "own")
    detect_set(small, get_preset("default").replace(max_side=1280), again, workers=1)
    assert again.misses == 0 and again.hits > 0


def test_photos_without_cameras_share_a_pencil_of_planes_and_explain_it(tmp_path):
    """A set run without its reconstruction: each photo's epipolar supports are swept over one
    pencil compatible with their F's (pipeline/pencil.py), and a pixel's explanation puts the
    agreed hypothesis on the pair's epipolar line."""
    from pipeline.cache import PairCache
    from pipeline.explain import explain_pixel
    from pipeline.geometry import epipolar_lines
    from pipeline.loading import load_set
    from pipeline.params import get_preset
    from pipeline.run import detect_set

    ps = load_set(SAMPLE_SETS / "street_sideways", 240)
    params = get_preset("default").replace(max_side=240).with_settings(["geometry.reconstruction=false"])
    res = detect_set(ps, params, PairCache(tmp_path), workers=1)
    kinds = {ij: res.sweep_kind(*ij) for ij in res.pair_results}
    pencils = [ij for ij, k in kinds.items() if k == "two-view"]
    assert pencils and "sweep" not in kinds.values()
    by_ref = {}
    for i, j in pencils:
        by_ref.setdefault(i, []).append(j)
    limit = params.geometry.recon_max_uncertainty_frac * 240
    for i, sups in by_ref.items():        # a lone support has no other to check its F: certain lines
        assert len(sups) >= 2 or res.pairs[(i, sups[0])].uncertainty_px <= limit
    i, sups = max(by_ref.items(), key=lambda kv: len(kv[1]))
    j = sups[0]
    assert len(sups) >= 2 and res.fused(i, sups) is not None
    h, w = ps.photos[i].size
    ev = explain_pixel(res, i, j, (w / 2, h / 2), res.supports[i])
    assert ev.strip is not None and ev.depth_point is not None and not np.isfinite(ev.depth)
    line = epipolar_lines(res.pairs[(i, j)].F, np.array([[w / 2, h / 2]]))[0]
    for q in (*ev.strip, ev.depth_point):
        assert abs(line @ np.append(q, 1.0)) < 0.5
    # a photo whose cue rests on its one pencil support (no other support's F answers to that pair's)
    # counts it at sweep.lone_pencil_weight; the cue of a pencil of two or more is unchanged
    full = params.with_settings(["sweep.lone_pencil_weight=1"])
    lone = [i for i, sups in by_ref.items() if [j for j in res.supports[i] if res.is_swept(i, j)] == sups == [sups[0]]]
    assert lone and 0 < params.sweep.lone_pencil_weight < 1
    for i in by_ref:
        weight = params.sweep.lone_pencil_weight if i in lone else 1.0
        np.testing.assert_allclose(res.sweep_log_odds(i, res.supports[i]),
                                   weight * res.sweep_log_odds(i, res.supports[i], full), atol=1e-6)
    # a partial result (the inspector's, while pairs arrive) with one pair of a two-support pencil
    # counts that support whole: whether a pencil is lone is the run's plan, not what has arrived
    from pipeline.run import assemble
    i, sups = next((i, sups) for i, sups in by_ref.items() if len(sups) == 2)
    first = {ij: res.pair_results[ij] for ij in res.pair_results if ij != (i, sups[1])}
    partial = assemble(ps, res.params, res.pairs, res.supports, first, cameras=res.cameras)
    assert [j for j in res.supports[i] if partial.is_swept(i, j)] == [j for j in sups if j != sups[1]]
    assert partial.lone_pencil(i) is None and res.lone_pencil(i) is None
    assert all(partial.lone_pencil(k) == res.lone_pencil(k) for k in by_ref)
    # without the pencil the same photos have no depth cue
    off = detect_set(ps, params.with_settings(["sweep.two_view=false"]), PairCache(tmp_path), workers=1)
    assert all(off.sweep_kind(*ij) is None for ij in off.pair_results if off.pairs[ij].F is not None)


def test_a_lone_pencil_support_needs_certain_lines(tmp_path):
    """A photo with one epipolar support has no other to check that pair's F through shared
    tracks: it is swept only when the pair's lines are as certain as the cameras' sweep asks."""
    from pipeline.cache import PairCache
    from pipeline.loading import load_set
    from pipeline.params import get_preset
    from pipeline.run import detect_set

    ps = load_set(SAMPLE_SETS / "low_collinear", 240)
    params = get_preset("default").replace(max_side=240).with_settings(["geometry.reconstruction=false"])
    res = detect_set(ps, params, PairCache(tmp_path), workers=1)
    limit = params.geometry.recon_max_uncertainty_frac * 240
    lone = {i: s[0] for i, s in enumerate([[j for j in sup if res.pairs[(i, j)].F is not None]
                                            for i, sup in enumerate(res.supports)]) if len(s) == 1}
    uncertain = [i for i, j in lone.items() if res.pairs[(i, j)].uncertainty_px > limit]
    assert uncertain
    for i in uncertain:
        assert res.sweep_kind(i, lone[i]) is None
    assert any(k == "two-view" for k in (res.sweep_kind(*ij) for ij in res.pair_results))


def test_shots_from_one_spot_are_compared_at_the_working_resolution(tmp_path):
    """`sweep.aligned_side` 640 in default: a photo whose swept supports are all aligned pairs (shots
    from its own spot) fuses their direct comparisons at the working resolution up to 640 px, not
    the planes' half grid, and a pixel's explanation reads the cost of that grid."""
    from pipeline.cache import PairCache
    from pipeline.explain import explain_pixel
    from pipeline.loading import load_set
    from pipeline.params import get_preset
    from pipeline.run import detect_set

    ps = load_set(SAMPLE_SETS / "square_same_spot", 240)
    params = get_preset("default").replace(max_side=240)
    assert params.sweep.aligned_side == 640
    res = detect_set(ps, params, PairCache(tmp_path), workers=1)
    i = next(k for k, sups in enumerate(res.supports) if sups)
    sw = [j for j in res.supports[i] if res.sweep_kind(i, j) == "aligned"]
    assert sw and sw == res.supports[i]
    f = res.fused(i, sw)
    h, w = ps.photos[i].size
    assert f.cost.shape == (h, w)
    ev = explain_pixel(res, i, sw[0], (w / 3, h / 2), sw)
    gx, gy = int(round(w / 3)), int(round(h / 2))
    assert ev.cost == pytest.approx(float(f.per_support[0, gy, gx]), nan_ok=True)
    # the same photos at the planes' grid when the setting is off
    half = detect_set(ps, params.with_settings(["sweep.aligned_side=0"]), PairCache(tmp_path), workers=1)
    assert half.fused(i, sw).cost.shape == (round(h * params.sweep.scale), round(w * params.sweep.scale))
    # beside a planes' volume the direct comparison is fused at the planes' grid, and explained there
    ps = load_set(SAMPLE_SETS / "low_collinear", 240)
    res = detect_set(ps, params, PairCache(tmp_path), workers=1)
    mixed = [(i, [j for j in sups if res.is_swept(i, j)]) for i, sups in enumerate(res.supports)]
    i, sw = next((i, sw) for i, sw in mixed if {res.sweep_kind(i, j) for j in sw} >= {"aligned", "sweep"})
    h, w = ps.photos[i].size
    gh, gw = round(h * params.sweep.scale), round(w * params.sweep.scale)
    f = res.fused(i, sw)
    assert f.cost.shape == (gh, gw)
    k = next(k for k, j in enumerate(sw) if res.sweep_kind(i, j) == "aligned")
    ys, xs = np.nonzero(np.isfinite(f.per_support[k]))
    gy, gx = ys[len(ys) // 2], xs[len(xs) // 2]
    ev = explain_pixel(res, i, sw[k], ((gx + 0.5) * w / gw - 0.5, (gy + 0.5) * h / gh - 0.5), sw)
    assert ev.cost == pytest.approx(float(f.per_support[k, gy, gx]))
    assert ev.curve[0] == pytest.approx(ev.cost, abs=1e-6)             # its one cost, read on that grid
    assert ev.fused_curve[f.plane[gy, gx]] == pytest.approx(float(f.cost[gy, gx]), abs=1e-6)


def test_the_same_spot_limit_is_a_share_of_the_photo_side(tmp_path):
    """A swept support counts as taken from the reference's spot when its match moves less than
    `sweep.same_spot_frac` of the working side over the depth range: the same scene at
    any working size (it was 8 working px, which at 320 px took in supports 2.5 % of the side apart)."""
    from pipeline.cache import PairCache
    from pipeline.loading import load_set
    from pipeline.params import get_preset
    from pipeline.run import detect_set

    small = load_set(SAMPLE_SETS / "tabletop_ball", 320)
    res = detect_set(small, get_preset("default").replace(max_side=320), PairCache(tmp_path), workers=1)
    i = next(k for k in range(len(small.photos)) if any(res.sweep_kind(k, j) == "sweep" for j in res.supports[k]))
    sw = [j for j in res.supports[i] if res.sweep_kind(i, j) == "sweep"]
    side = res.params.max_side
    assert side == small.working_side == 320
    frac = res.params.sweep.same_spot_frac
    assert frac > 0
    for share, expected in [(0.8 * frac, True), (1.2 * frac, False)]:
        res.depth_span = lambda a, b, share=share: share * side       # the pair's span, as a share of the side
        assert res.same_spot(i, sw).tolist() == [expected] * len(sw)
