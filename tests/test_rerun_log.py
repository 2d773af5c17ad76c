"""Rerun logging: record a small sample set and read it back (rerun.chunk.RrdReader)."""

import json

import numpy as np
import pytest
import rerun as rr
from rerun.chunk import RrdReader

from conftest import SAMPLE_SETS
from pipeline.cache import PairCache
from pipeline.loading import load_set
from pipeline.params import get_preset
from pipeline.rerun_log import choose_focus, log_run, part
from pipeline.run import detect_set


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("rr")
    params = get_preset("default").replace(max_side=240)
    ps = load_set(SAMPLE_SETS / "tabletop_ball", params.max_side)
    res = detect_set(ps, params, PairCache(tmp / "cache"), workers=2)
    path = tmp / "run.rrd"
    rec = rr.RecordingStream("crowdcam", recording_id="test")
    rec.save(str(path))
    desc = log_run(res, rec)
    rec.disconnect()
    return res, desc, RrdReader(str(path)).store(), path


def _chunks(store, entity):
    return store.stream().filter(content=entity).to_chunks()


def _image(rb, kind):
    fmt = rb.column(f"{kind}:format")[0].as_py()[0]
    dtype = {6: np.uint8, 8: np.uint16}[fmt["channel_datatype"]]
    buf = rb.column(f"{kind}:buffer").flatten().flatten().to_numpy().tobytes()
    return np.frombuffer(buf, dtype).reshape(fmt["height"], fmt["width"])


def test_entity_tree(recording):
    res, desc, store, _ = recording
    paths = set(map(str, store.schema().entity_paths()))
    f = desc["focus"]
    s0 = desc["supports"][0]
    for p in res.photo_set.photos:
        assert f"/images/{part(p.stem)}" in paths
    for e in (f"/pairs/{f}/{s0}/info", f"/pairs/{f}/{s0}/mismatch", f"/pairs/{f}/{s0}/ref/epilines",
              f"/pairs/{f}/{s0}/sup/epilines", f"/pairs/{f}/{s0}/sup/candidates", f"/pairs/{f}/{s0}/no_evidence", f"/pairs/{f}/{s0}/ref/patches",
              f"/dynamic/{f}/prob", f"/dynamic/{f}/mask", f"/dynamic/{f}/sweep", "/params", "/meta/blueprint"):
        assert e in paths, e


def test_logged_aggregate_equals_the_pipeline(recording):
    res, desc, store, _ = recording
    i = choose_focus(res)
    (ch,) = _chunks(store, f"/dynamic/{desc['focus']}/prob")
    logged = _image(ch.to_record_batch(), "DepthImage") / 65535.0
    assert logged.shape == res.dynamic[i].shape
    assert np.abs(logged - res.dynamic[i]).max() < 1e-4


def test_match_prob_and_sweep(recording):
    """P(x|I_s) is logged as 1 - P, so that blue (low) means matched as in the inspector."""
    res, desc, store, _ = recording
    i = choose_focus(res)
    j = res.supports[i][0]
    (ch,) = _chunks(store, f"/pairs/{desc['focus']}/{part(res.photo_set.photos[j].stem)}/mismatch")
    logged = _image(ch.to_record_batch(), "DepthImage") / 255.0
    assert np.abs(logged - (1.0 - res.match_prob(i, j))).max() <= 0.5 / 255 + 1e-6
    rows = []
    for ch in _chunks(store, f"/dynamic/{desc['focus']}/sweep"):
        rb = ch.to_record_batch()
        for r in range(rb.num_rows):
            rows.append((rb.column("supports")[r].as_py(), _image(rb.slice(r, 1), "DepthImage")))
    rows.sort(key=lambda t: t[0])
    assert [k for k, _ in rows] == list(range(1, len(res.supports[i]) + 1))
    assert np.abs(rows[-1][1] / 255.0 - res.dynamic[i]).max() <= 0.5 / 255 + 1e-6


def test_candidates_follow_the_patch_timeline(recording):
    res, desc, store, _ = recording
    f, s0 = desc["focus"], desc["supports"][0]
    cand = [ch.to_record_batch() for ch in _chunks(store, f"/pairs/{f}/{s0}/sup/candidates")]
    best = [ch.to_record_batch() for ch in _chunks(store, f"/pairs/{f}/{s0}/sup/best")]
    steps = sorted(v for rb in cand for v in rb.column("patch").to_pylist())
    assert len(steps) >= 4 and steps == sorted(set(steps))
    # a patch whose strip is out of the support's view logs a Clear instead (no candidate)
    drawn = [rb for rb in cand if "LineStrips2D:strips" in rb.schema.names]
    n_strips = [len(rb.column("LineStrips2D:strips")[r].as_py()) for rb in drawn for r in range(rb.num_rows)]
    assert len(n_strips) >= 3 and min(n_strips) > 10     # every position along the strip, 3 widths
    labels = [l for rb in best if "LineStrips2D:labels" in rb.schema.names
              for r in range(rb.num_rows) for l in rb.column("LineStrips2D:labels")[r].as_py()]
    assert any(l.startswith("best HOG") for l in labels) and any(l.startswith("best colour") for l in labels)


def test_fan_is_one_batch_and_blueprint_is_stored(recording):
    res, desc, store, path = recording
    i = choose_focus(res)
    j = res.supports[i][0]
    r = res.pair_results[(i, j)]
    (ch,) = _chunks(store, f"/pairs/{desc['focus']}/{part(res.photo_set.photos[j].stem)}/ref/epilines")
    strips = ch.to_record_batch().column("LineStrips2D:strips")[0].as_py()
    assert len(strips) == int((r.strips.fan == 0).sum())
    (bp,) = _chunks(store, "/meta/blueprint")
    assert json.loads(bp.to_record_batch().column("TextDocument:text")[0].as_py()[0]) == desc
    assert path.stat().st_size < 150 * 2**20


def test_every_reference_has_candidates(recording):
    """The recording explains every reference, not only the first: candidates for at least one
    epipolar pair of each photo that has one."""
    res, desc, store, _ = recording
    paths = set(map(str, store.schema().entity_paths()))
    for i, p in enumerate(res.photo_set.photos):
        epi = [j for j in res.supports[i] if res.pair_results[(i, j)].kind == "epipolar"]
        if res.dynamic[i] is None or not epi:
            continue
        assert any(f"/pairs/{part(p.stem)}/{part(res.photo_set.photos[j].stem)}/sup/candidates" in paths
                   for j in epi), p.stem
    assert res.pair_results[(choose_focus(res), [j for j in res.supports[choose_focus(res)]][0])].kind in (
        "epipolar", "homography")
    first = desc["supports"][0]
    k = [part(q.stem) for q in res.photo_set.photos].index(first)
    assert res.pair_results[(choose_focus(res), k)].kind == "epipolar"      # the first screen has lines


def test_cameras_in_3d(recording):
    res, desc, store, _ = recording
    paths = set(map(str, store.schema().entity_paths()))
    assert desc["has_cameras"]
    assert "/world/points" in paths
    for k in np.nonzero(res.cameras.registered)[0]:
        assert f"/world/cameras/{part(res.photo_set.photos[k].stem)}/image" in paths


def test_the_plane_cue_is_recorded_where_the_map_has_it(recording):
    res, _, store, _ = recording
    paths = set(map(str, store.schema().entity_paths()))
    with_cue = [i for i, s in enumerate(res.supports) if s and res.plane_log_odds(i, s) is not None]
    assert with_cue
    for i in with_cue:
        assert f"/dynamic/{part(res.photo_set.photos[i].stem)}/plane_cue" in paths


def test_ground_truth_and_jaccard_on_the_first_screen(recording, tmp_path):
    """With ground truth: its outline (green, as in the inspector) and the Jaccard at the mask's
    threshold, scored at the original size as `crowdcam eval` does, both in the first view."""
    from pipeline.evaluate import jaccard
    from pipeline.loading import load_gts
    from pipeline.output import to_original
    from pipeline.rerun_log import GT_RGB, make_blueprint
    res = recording[0]
    gts = load_gts(res.photo_set)
    path = tmp_path / "gt.rrd"
    rec = rr.RecordingStream("crowdcam", recording_id="test-gt")
    rec.save(str(path))
    desc = log_run(res, rec, gts=gts, threshold=0.4)
    rec.disconnect()
    store = RrdReader(str(path)).store()
    i = choose_focus(res)
    photo = res.photo_set.photos[i]
    want = jaccard(to_original(res.dynamic[i], photo) > 0.4, gts[photo.stem])
    assert desc["jaccard"].startswith(f"Jaccard {want:.2f} at the threshold 0.40")
    (ch,) = _chunks(store, f"/dynamic/{desc['focus']}/gt_outline")
    rb = ch.to_record_batch()
    assert len(rb.column("LineStrips2D:strips")[0].as_py()) >= 1
    colour = rb.column("LineStrips2D:colors")[0].as_py()[0]
    assert colour == (GT_RGB[0] << 24) | (GT_RGB[1] << 16) | (GT_RGB[2] << 8) | 255
    (ch,) = _chunks(store, f"/dynamic/{desc['focus']}/jaccard")
    assert ch.to_record_batch().column("TextDocument:text")[0].as_py()[0] == desc["jaccard"]
    make_blueprint(desc)                                  # the title carries it; it builds
