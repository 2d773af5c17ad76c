"""The inspector's computation side (no browser): its maps are the pipeline's maps, evidence
agrees with the pair tables, background runs fill in, and redraws coalesce (last value wins)."""

import dataclasses
import threading
import time

import numpy as np
import pytest

from conftest import SAMPLE_SETS


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    from inspector.model import SetModel
    from pipeline.cache import PairCache
    from pipeline.loading import load_set
    ps = load_set(SAMPLE_SETS / "tabletop_ball", 256)
    events = []
    model = SetModel(ps, "default", PairCache(tmp_path_factory.mktemp("cache")), max_side=256)
    model.add_listener(lambda m: events.append((m.status, len(m.results))))
    model.start()._thread.join(timeout=600)
    assert model.status == "done", model.error
    return model, events


def all_supports(run):
    """(snapshot, first reference, a fresh TermCache, default settings with all its supports on)."""
    from inspector.model import Settings, TermCache
    model, _ = run
    snap = model.snapshot()
    i = model.first_ref
    return snap, i, TermCache(), dataclasses.replace(Settings.for_preset("default", i, 256),
                                                     supports=tuple(snap.supports[i]))


def test_background_run_reports_pairs_as_they_finish(run):
    model, events = run
    counts = [n for _, n in events]
    assert counts == sorted(counts) and counts[-1] == len(model.results) > 1
    assert len(set(counts)) > 2                      # the snapshot grew in steps, not all at once
    assert events[-1][0] == "done"
    snap = model.snapshot()
    assert snap is model.snapshot()                  # unchanged until another pair finishes
    # the reference shown first is computed first
    first = [ij for ij in model.results][0]
    assert first[0] == model.first_ref


def test_pair_states_name_rejections(run):
    model, _ = run
    states = {(i, j): model.pair_state(i, j) for (i, j) in model.pairs}
    assert {s for s, _ in states.values()} <= {"ready", "rejected"}
    for (i, j), (state, why) in states.items():
        assert (state == "ready") == model.pairs[(i, j)].ok
        if state == "rejected":
            assert why == model.pairs[(i, j)].reason and why


def test_settings_of_a_preset_are_the_preset():
    from inspector.model import Settings
    from pipeline.params import get_preset
    for name in ("paper", "default"):
        assert Settings.for_preset(name, max_side=512).params() == get_preset(name).replace(max_side=512)


def test_param_changes_reach_every_preset_the_inspector_runs(tmp_path):
    """`crowdcam inspect --param`: the changes are in the tab's settings (the threshold slider starts
    at the changed value), in its params and in the run's, whatever the preset; a bad one names itself."""
    from inspector.model import SetModel, Settings, preset_params
    from pipeline.cache import PairCache
    from pipeline.loading import load_set
    changes = ("aggregate.threshold=0.2", "geometry.affine_tilts=1")
    for name in ("paper", "default"):
        s = Settings.for_preset(name, 0, 256, changes)
        assert s.threshold == 0.2 and s.params().geometry.affine_tilts == 1
        assert s.params() == preset_params(name, 256, changes) != Settings.for_preset(name, 0, 256).params()
    model = SetModel(load_set(SAMPLE_SETS / "tabletop_ball", 256), "default", PairCache(tmp_path), 256,
                     changes=changes)
    assert model.params.geometry.affine_tilts == 1 and model.params.aggregate.threshold == 0.2
    with pytest.raises(ValueError, match="nope"):
        Settings.for_preset("default", 0, 256, ("sweep.nope=1",))


def test_reaggregation_equals_the_pipeline(run):
    """The cached per-support terms give exactly Eq. 3 as SetResult computes it, for any subset of
    supports and any remap / weights / no-evidence choice."""
    from inspector.model import Settings, TermCache, dynamic_prob
    model, _ = run
    snap = model.snapshot()
    i = model.first_ref
    sups = snap.supports[i]
    assert len(sups) >= 2
    terms = TermCache()
    base = Settings.for_preset("default", i, 256)
    variants = [dataclasses.replace(base, supports=tuple(sups)),
                dataclasses.replace(base, supports=tuple(sups[1:])),
                dataclasses.replace(base, supports=tuple(sups), remap=(0.1, 0.9), w_hog=0.5, w_color=3.0,
                                    no_evidence="no_match", refine=False)]
    for s in variants:
        ours = dynamic_prob(snap, s, terms)
        want = snap.dynamic_prob(i, list(s.supports), s.params())
        np.testing.assert_allclose(ours, want, atol=1e-5)
        assert dynamic_prob(snap, dataclasses.replace(s, threshold=0.9), terms) is ours   # threshold: cached
    assert dynamic_prob(snap, dataclasses.replace(base, supports=()), terms) is None


def test_sweep_ends_with_the_main_map(run):
    from inspector import compose
    from inspector.model import dynamic_prob
    snap, i, terms, s = all_supports(run)
    view = compose.sweep(snap, s, terms)
    assert view.supports == tuple(snap.supports[i])
    np.testing.assert_allclose(view.maps[-1], dynamic_prob(snap, s, terms), atol=1e-5)
    for k in range(1, len(view.maps) + 1):
        sk = dataclasses.replace(s, supports=view.supports[:k])
        np.testing.assert_allclose(view.maps[k - 1], dynamic_prob(snap, sk, terms), atol=1e-5)


def test_pixel_evidence_agrees_with_the_pair_table(run):
    """Eq. 1: a patch's confidence is its best candidate's similarity; the search line is F x."""
    from inspector import compose
    from inspector.model import dynamic_prob
    snap, i, terms, s = all_supports(run)
    dyn = dynamic_prob(snap, s, terms)
    h, w = dyn.shape
    xy = np.array([w * 0.5, h * 0.6])
    rep = compose.explain(snap, s, terms, dyn, xy)
    assert rep.dynamic == pytest.approx(float(dyn[round(xy[1]), round(xy[0])]))
    assert len(rep.evidence) == len(snap.supports[i])
    for e, val in zip(rep.evidence, rep.values):
        assert 0.0 <= val <= 1.0
        pair = snap.pair_results[(i, e.sup)]
        if e.kind == "epipolar":
            F = snap.pairs[(i, e.sup)].F
            np.testing.assert_allclose(e.line, F @ np.array([xy[0], xy[1], 1.0]))
        else:
            q = pair.H @ np.array([xy[0], xy[1], 1.0])
            np.testing.assert_allclose(e.point, q[:2] / q[2])
        if e.patch is not None and len(e.patch.cand_quads):
            t = pair.patches
            assert e.patch.sim_hog[e.patch.best_hog] == pytest.approx(t.conf_hog[e.patch.patch], abs=1e-4)
            assert e.patch.sim_color[e.patch.best_color] == pytest.approx(t.conf_color[e.patch.patch], abs=1e-4)
    md = compose.report_markdown(rep, [p.stem for p in snap.photo_set.photos], "ref", 0.5)
    assert f"**{rep.dynamic:.2f}**" in md


def test_homography_pixel_evidence():
    """On a set of shots from one spot every pair is a homography pair: the pixel maps to H x and
    the best candidates sit in the search window."""
    from inspector import compose
    from inspector.model import Settings, TermCache, dynamic_prob
    from pipeline.cache import PairCache
    from pipeline.loading import load_set
    from pipeline.params import get_preset
    from pipeline.run import detect_set
    ps = load_set(SAMPLE_SETS / "square_same_spot", 200)
    res = detect_set(ps, get_preset("default").replace(max_side=200), PairCache(None), workers=1, only_refs=[0])
    s = dataclasses.replace(Settings.for_preset("default", 0, 200), supports=tuple(res.supports[0]))
    terms = TermCache()
    dyn = dynamic_prob(res, s, terms)
    rep = compose.explain(res, s, terms, dyn, np.array([100.0, 70.0]))
    hom = [e for e in rep.evidence if e.kind == "homography"]
    assert hom
    for e in hom:
        assert e.window is not None and e.patch is not None
        lo, hi = e.window.min(axis=0) - 1, e.window.max(axis=0) + 1
        for q in e.patch.cand_quads:
            assert np.all(q.min(axis=0) >= lo) and np.all(q.max(axis=0) <= hi)
        assert np.all(e.point >= lo) and np.all(e.point <= hi)


def test_redrawer_draws_the_last_value_only():
    from inspector.app import Redrawer
    state = {"v": 0}
    drawn = []
    gate = threading.Event()

    def draw(what):
        gate.wait(5)
        drawn.append((state["v"], frozenset(what)))

    r = Redrawer("test", draw)
    try:
        for v in range(1, 51):          # 50 rapid changes while the first draw is busy
            state["v"] = v
            r.request("main" if v % 2 else "supports")
            time.sleep(0.001)
        gate.set()
        assert r.wait_idle(10)
        assert len(drawn) <= 3
        assert drawn[-1][0] == 50
        assert set().union(*(w for _, w in drawn)) == {"main", "supports"}
    finally:
        r.stop()


def test_overlay_layers():
    from inspector import render
    rgb = np.full((40, 60, 3), 100, np.uint8)
    dyn = np.zeros((40, 60), np.float32)
    dyn[10:30, 20:40] = 0.9
    assert np.array_equal(render.overlay(rgb, None, 0.5, render.Layers()), rgb)
    off = render.overlay(rgb, dyn, 0.5, render.Layers(heat=False, mask=False, gt=False))
    assert np.array_equal(off, rgb)
    masked = render.overlay(rgb, dyn, 0.5, render.Layers(heat=False, mask=True))
    assert tuple(masked[10, 30]) == render.MASK_RGB          # the outline
    assert np.array_equal(masked[0, 0], rgb[0, 0])           # outside untouched
    assert not np.array_equal(render.overlay(rgb, dyn, 0.95, render.Layers()),
                              render.overlay(rgb, dyn, 0.5, render.Layers()))


def test_support_tiles_draw_a_match_blue_and_no_match_red(run):
    """The Supports tab's caption says blue = matched (static), red = no match, like the main map:
    supports that mostly match must come out mostly blue."""
    from inspector import compose
    snap, i, terms, s = all_supports(run)
    assert min(terms.match_prob(snap, i, j, s.params()).mean() for j in snap.supports[i]) > 0.5
    tiles = compose.support_mosaic(snap, s, terms, ["x"] * len(snap.photo_set.photos)).astype(int)
    assert (tiles[..., 2] - tiles[..., 0]).mean() > 20      # blue over red


def test_the_fusion_table_adds_up(run):
    """For a clicked pixel, the votes' running sum ends at the total, the total is the pipeline's
    static log-odds there (negated), the formula gives the unrefined P_dynamic, and the map shows
    the refined one; for `default` (mean of the supports' terms, the depth cue, the calibration)
    and for the paper's aggregation (the plain sum of Eq. 3)."""
    from inspector import compose
    from inspector.model import Settings, dynamic_prob
    from pipeline.aggregate import support_log_odds
    snap, i, terms, s = all_supports(run)
    stems = [p.stem for p in snap.photo_set.photos]
    paper = dataclasses.replace(Settings.for_preset("paper", i, 256), supports=s.supports)
    h, w = snap.photo_set.photos[i].size
    for settings in (s, paper):
        p = settings.params()
        sups = list(snap.supports[i])
        dyn = dynamic_prob(snap, settings, terms)
        p_raw = dataclasses.replace(settings, refine=False).params()
        raw = snap.dynamic_prob(i, sups, p_raw.replace(aggregate=dataclasses.replace(p_raw.aggregate, plane_weight=0.0)))
        for fx, fy in ((0.5, 0.6), (0.2, 0.3), (0.8, 0.8)):
            xy = np.array([fx * w, fy * h])
            u, v = round(xy[0]), round(xy[1])
            f = compose.explain(snap, settings, terms, dyn, xy, stems).fusion
            assert f.method == "votes"
            running = 0.0
            for r in f.rows:
                running += r.vote
                assert r.total == pytest.approx(running, abs=1e-9)
            assert f.rows[-1].total == pytest.approx(f.total)
            if p.sweep.enabled:
                z = float(snap.static_log_odds(i, sups, p)[v, u])
                assert [r.kind for r in f.rows][-1] == "depth"
            else:
                z = float(sum(support_log_odds(snap.match_prob(i, j, p), p.aggregate)[v, u] for j in sups))
                assert len(f.rows) == len(sups)
            assert -f.total == pytest.approx(z, abs=1e-4)
            assert f.p_raw == pytest.approx(float(raw[v, u]), abs=1e-4)
            assert f.p_map == pytest.approx(float(dyn[v, u]))
            if p.aggregate.plane_weight > 0:       # the plane cue, added after the filter, at this pixel
                z = snap.plane_log_odds(i, sups, p)
                a = p.aggregate
                assert f.plane_vote == pytest.approx(-a.plane_weight * float(z[v, u]), abs=1e-5)
            steps = compose.after_the_sum(f)          # the chart's last rows end at the map's value
            if steps and f.speaks:
                running = f.total
                for _, step, total, _ in steps:
                    running += step
                    assert total == pytest.approx(running, abs=1e-9)
                end = 1 / (1 + np.exp(-f.scale * (steps[-1][2] + f.offset)))
                assert end == pytest.approx(f.p_map, abs=1e-5)
            md = compose.fusion_markdown(compose.PixelReport(xy, f.p_map, (), (), fusion=f))
            assert f"**{f.p_raw:.2f}**" in md and f"**{f.p_map:.2f}**" in md


def test_peer_baseline_fusion_is_the_median():
    from inspector import compose
    from inspector.model import Settings, TermCache, dynamic_prob
    from pipeline.cache import PairCache
    from pipeline.loading import load_set
    from pipeline.params import get_preset
    from pipeline.run import detect_set
    ps = load_set(SAMPLE_SETS / "tabletop_ball", 256)
    res = detect_set(ps, get_preset("peer-homography").replace(max_side=256), PairCache(None), workers=1)
    i = int(np.argmax([len(sup) for sup in res.supports]))
    s = dataclasses.replace(Settings.for_preset("peer-homography", i, 256), supports=tuple(res.supports[i]))
    terms = TermCache()
    dyn = dynamic_prob(res, s, terms)
    rep = compose.explain(res, s, terms, dyn, np.array([80.0, 60.0]))
    f = rep.fusion
    assert f.method == "median" and len(f.rows) == len(res.supports[i]) >= 2
    assert f.p_raw == pytest.approx(float(dyn[60, 80]), abs=1e-5)       # no refinement in this preset
    assert all(e.kind == "peer" and e.point is not None for e in rep.evidence)
    assert "median" in compose.fusion_markdown(rep)


def test_map_notice_says_when_nothing_is_marked():
    from inspector import compose
    dyn = np.linspace(0.02, 0.41, 100, dtype=np.float32).reshape(10, 10)
    n = compose.map_notice("cam01", dyn, 0.5, 3)
    assert n.empty and "0.02–0.41" in n.text and "0.50" in n.text
    assert not compose.map_notice("cam01", dyn, 0.3, 3).empty
    assert compose.map_notice("cam01", dyn, 0.3, 1).doubtful          # one support
    assert compose.map_notice("cam01", np.full((4, 4), 0.5, np.float32), 0.6, 3).doubtful   # no evidence
