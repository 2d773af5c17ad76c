"""Failure gallery (pipeline/gallery.py) on cases built to have a known cause, and `crowdcam
report` end to end on a small bundled set."""

import json
import re
import subprocess
import sys

import numpy as np
import pytest

from conftest import ROOT, SAMPLE_SETS, project
from pipeline.gallery import (FALSE_ALARM, MISSED, UNCERTAIN, ReferenceEvidence, cue_summary, diagnose,
                              find_regions, gallery_from_evidence, signed, strip_probe)
from pipeline.params import get_preset

H, W, L = 60, 80, 24          # image size and patch length of the built cases


def evidence(dynamic, gt=None, match_prob=None, hog=None, colour=None, seen=None, unc=None, depth_cost=None, S=4):
    """A ReferenceEvidence of S supports that all see every pixel and match moderately (P 0.6,
    HOG 0.65, colour 0.3: HOG runs higher than colour, as on real sets), unless told otherwise."""
    full = lambda v: np.full((S, H, W), v, np.float32)
    return ReferenceEvidence(
        "ref", np.asarray(dynamic, np.float32), 0.5, gt, tuple(f"s{k}" for k in range(S)),
        full(0.6) if match_prob is None else match_prob, full(0.65) if hog is None else hog,
        full(0.3) if colour is None else colour, full(1.0) if seen is None else seen, full(np.nan), depth_cost, 0.3,
        np.full(S, 1.0, np.float32) if unc is None else np.asarray(unc, np.float32),
        ("reconstruction",) * S, L)


def square(y0, x0, n):
    m = np.zeros((H, W), bool)
    m[y0:y0 + n, x0:x0 + n] = True
    return m


# ----------------------------------------------------------------------------- regions
def test_regions_are_components_ranked_by_area_per_kind():
    gt = np.zeros((H, W), np.uint8)
    big, small, lit = square(5, 5, 15), square(30, 40, 8), square(40, 5, 10)
    gt[big | small] = 255
    gt[square(0, 70, 6)] = 128                     # don't care: never a false alarm
    dyn = np.full((H, W), 0.2, np.float32)
    dyn[lit] = 0.8                                 # static, lit up
    dyn[square(0, 70, 6)] = 0.9
    dyn[5:20, 5:10] = 0.9                          # a third of the big mover found
    regions = find_regions(dyn, 0.5, gt, min_area=4, open_px=1)
    missed = [r for r in regions if r.kind == MISSED]
    false = [r for r in regions if r.kind == FALSE_ALARM]
    assert [(r.rank, r.area) for r in missed] == [(1, 15 * 10), (2, 64)]
    assert [(r.rank, r.area) for r in false] == [(1, 100)]
    assert missed[0].bbox == (10, 5, 20, 20) and missed[0].object_area == 225
    assert np.isclose(missed[0].object_found, 75 / 225) and missed[1].object_found == 0.0
    x, y = missed[1].pixel                         # the point deepest inside: the centre
    assert 33 <= y <= 34 and 43 <= x <= 44
    assert missed[0].full_mask((H, W)).sum() == 150 and np.isclose(false[0].mean_p, 0.8)


def test_slivers_and_specks_are_not_regions():
    gt = np.zeros((H, W), np.uint8)
    gt[square(10, 10, 20)] = 255
    dyn = np.zeros((H, W), np.float32)
    dyn[square(10, 10, 20)] = 0.9
    dyn[10:30, 9] = 0.9                            # the mask one pixel wider than the truth: a sliver
    dyn[50, 50] = 0.9                              # one speck
    assert find_regions(dyn, 0.5, gt, min_area=9, open_px=3) == []


def test_without_ground_truth_the_most_uncertain_regions_rank_first():
    dyn = np.full((H, W), 0.1, np.float32)
    dyn[square(5, 5, 12)] = 0.5                    # at the threshold: fully undecided
    dyn[square(30, 40, 16)] = 0.54                 # larger, less undecided (0.6 each)
    dyn[square(40, 5, 10)] = 0.95                  # clearly moving: not uncertain
    regions = find_regions(dyn, 0.5, None, min_area=4, open_px=1)
    assert all(r.kind == UNCERTAIN for r in regions) and len(regions) == 2
    assert regions[0].area == 256 and np.isclose(regions[0].score, 256 * 0.6, rtol=1e-3)
    assert regions[1].area == 144 and np.isclose(regions[1].score, 144.0)


def test_supports_that_disagree_make_a_region_uncertain_without_gt():
    dyn = np.full((H, W), 0.4, np.float32)         # inside two bands, not one: only disagreement lifts it
    mp = np.full((4, H, W), 0.6, np.float32)
    m = square(20, 20, 14)
    mp[0][m], mp[1][m] = 0.05, 0.95                # two supports say opposite things here
    ev = evidence(dyn, match_prob=mp)
    g = gallery_from_evidence(ev, min_area=16)
    assert [e.region.kind for e in g.entries] == [UNCERTAIN]
    assert abs(g.entries[0].region.area - 14 * 14) < 20


# ----------------------------------------------------------------------------- diagnoses
def _only_region(ev):
    regs = find_regions(ev.dynamic, ev.threshold, ev.gt, min_area=4, open_px=1)
    assert len(regs) == 1, regs
    return regs[0]


def test_a_mover_no_support_sees_is_diagnosed_so():
    gt = np.zeros((H, W), np.uint8)
    m = square(20, 20, 16)
    gt[m] = 255
    dyn = np.full((H, W), 0.2, np.float32)
    dyn[m] = 0.5                                   # no evidence: neutral, not above the threshold
    seen = np.ones((4, H, W), np.float32)
    seen[:, m] = 0.0
    hog = np.full((4, H, W), 0.65, np.float32)
    hog[:, m] = np.nan
    ev = evidence(dyn, gt, seen=seen, hog=hog, colour=np.where(np.isnan(hog), np.nan, 0.3).astype(np.float32))
    e = diagnose(ev, _only_region(ev))
    assert e.region.kind == MISSED and e.headline.code == "no_view"
    assert e.headline.figures["seeing"] == 0 and e.headline.figures["supports"] == 4
    assert all(not f["sees"] and f["vote"] == "does not see it" for f in e.support_figures)


def test_one_support_vetoes_a_static_region():
    gt = np.zeros((H, W), np.uint8)
    m = square(20, 20, 16)
    dyn = np.full((H, W), 0.2, np.float32)
    dyn[m] = 0.7
    mp = np.full((4, H, W), 0.7, np.float32)
    mp[2][m] = 0.1                                 # s2 alone finds no match
    e = diagnose(evidence(dyn, gt, match_prob=mp), _only_region(evidence(dyn, gt)))
    assert e.region.kind == FALSE_ALARM and e.headline.code == "veto"
    assert e.headline.figures["support"] == "s2" and e.headline.figures["others"] == 3


def test_colour_disagreeing_with_hog_is_named_against_the_photo_baseline():
    gt = np.zeros((H, W), np.uint8)
    m = square(20, 20, 16)
    dyn = np.full((H, W), 0.2, np.float32)
    dyn[m] = 0.7
    mp = np.full((4, H, W), 0.6, np.float32)
    colour = np.full((4, H, W), 0.3, np.float32)
    mp[:, m], colour[:, m] = 0.4, 0.02             # colour finds nothing here, HOG as usual
    e = diagnose(evidence(dyn, gt, match_prob=mp, colour=colour), _only_region(evidence(dyn, gt)))
    assert e.headline.code == "colour_hog" and e.headline.figures["departs"] == "colour"
    assert np.isclose(e.headline.figures["colour"], 0.02) and e.headline.figures["hog"] == 0.65
    # HOG running higher than colour everywhere is no disagreement
    e2 = diagnose(evidence(dyn, gt, match_prob=np.where(mp < 0.5, 0.4, 0.6).astype(np.float32)),
                  _only_region(evidence(dyn, gt)))
    assert "colour_hog" not in [d.code for d in e2.diagnoses]


def test_an_uncertain_pair_is_named_when_it_votes_the_wrong_way():
    gt = np.zeros((H, W), np.uint8)
    m = square(20, 20, 16)
    dyn = np.full((H, W), 0.2, np.float32)
    dyn[m] = 0.7
    mp = np.full((4, H, W), 0.7, np.float32)
    mp[1][m] = mp[3][m] = 0.2
    ev = evidence(dyn, gt, match_prob=mp, unc=[1.0, 14.0, 1.0, 2.0])     # s1's lines: 14 px, patch 24 px
    e = diagnose(ev, _only_region(ev))
    geo = next(d for d in e.diagnoses if d.code == "geometry")
    assert [s["support"] for s in geo.figures["supports"]] == ["s1"]
    # the same uncertainty on a support that votes the right way is no cause
    ev2 = evidence(dyn, gt, match_prob=mp, unc=[14.0, 1.0, 1.0, 1.0])
    assert "geometry" not in [d.code for d in diagnose(ev2, _only_region(ev2)).diagnoses]


def _perturbed(F_true, ref, sup, degrees):
    """The F of the same pair with the support camera tilted by `degrees` (about its x axis: the
    lines, nearly horizontal, move across themselves)."""
    import dataclasses

    from pipeline.geometry import fundamental_from_cameras
    a = np.radians(degrees)
    Rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    return fundamental_from_cameras(ref.P, dataclasses.replace(sup, R=Rx @ sup.R).P)


def test_a_perturbed_F_reads_as_geometry_and_a_far_candidate_as_a_look_alike(camera_pair):
    """Known answers from a synthetic camera pair: the true F passes through the true position of
    a point; an F with the support tilted by 2 degrees passes some 20 px away (the strip misses
    the point: geometry); with the true F, a best candidate 90 px along the line from the true
    position, better than the one there, is a look-alike."""
    ref, sup, F, X = camera_pair
    xr, xs = project(ref, X[:1])[0], project(sup, X[:1])[0]
    assert strip_probe("s0", F, xr, xs).line_px < 1e-6
    bad = strip_probe("s0", _perturbed(F, ref, sup, 2.0), xr, xs)
    assert bad.line_px > L / 2
    # a static region one support (s0, with the perturbed F) finds no match for
    gt = np.zeros((H, W), np.uint8)
    m = square(20, 20, 16)
    dyn = np.full((H, W), 0.2, np.float32)
    dyn[m] = 0.7
    mp = np.full((4, H, W), 0.7, np.float32)
    mp[0][m] = 0.1
    ev = evidence(dyn, gt, match_prob=mp)
    e = diagnose(ev, _only_region(ev), {"s0": bad})
    assert e.headline.code == "geometry" and e.headline.strength > 0.8
    assert e.headline.figures["supports"][0]["line_px"] == round(bad.line_px, 1)

    # a look-alike: true F, candidates along the true epipolar line; the best 90 px away
    line = F @ np.append(xr, 1.0)
    d = np.array([line[1], -line[0]]) / np.hypot(line[0], line[1])       # along the line
    centres = xs + np.outer([-90.0, 0.0, 8.0, 40.0], d)
    sims = np.array([0.85, 0.45, 0.5, 0.6])
    look = strip_probe("s1", F, xr, xs, centres, sims, 0, L)
    assert np.isclose(look.cand_px, 90.0) and look.line_px < 1e-6 and np.isclose(look.near_sim, 0.5)
    gt2 = np.zeros((H, W), np.uint8)
    gt2[m] = 255
    dyn2 = np.full((H, W), 0.2, np.float32)
    dyn2[m] = 0.45
    mp2 = np.full((4, H, W), 0.3, np.float32)
    mp2[1][m] = 0.8                                # s1 finds a match for the mover: the look-alike
    ev2 = evidence(dyn2, gt2, match_prob=mp2)
    e2 = diagnose(ev2, _only_region(ev2), {"s1": look})
    assert e2.region.kind == MISSED and e2.headline.code == "lookalike"
    assert e2.headline.figures["supports"][0]["support"] == "s1"
    # the same candidate with the perturbed F: the strip misses the point, geometry, not a look-alike
    e3 = diagnose(ev2, _only_region(ev2), {"s1": strip_probe("s1", _perturbed(F, ref, sup, 2.0), xr, xs,
                                                             centres, sims, 0, L)})
    assert e3.headline.code == "geometry" and "lookalike" not in [x.code for x in e3.diagnoses]
    # a candidate as good where the point should be: no look-alike
    e4 = diagnose(ev2, _only_region(ev2), {"s1": strip_probe("s1", F, xr, xs, centres,
                                                             np.array([0.85, 0.8, 0.5, 0.6]), 0, L)})
    assert "lookalike" not in [x.code for x in e4.diagnoses]


def test_depth_cue_without_agreement_explains_a_static_false_alarm():
    gt = np.zeros((H, W), np.uint8)
    m = square(20, 20, 16)
    dyn = np.full((H, W), 0.2, np.float32)
    dyn[m] = 0.7
    cost = np.full((H, W), 0.2, np.float32)
    cost[m] = 0.45                                 # no depth at which the supports agree
    e = diagnose(evidence(dyn, gt, depth_cost=cost), _only_region(evidence(dyn, gt)))
    assert e.headline.code == "depth" and e.headline.figures["depth_cost"] == 0.45


def test_gallery_keeps_the_first_k_of_each_kind():
    gt = np.zeros((H, W), np.uint8)
    dyn = np.full((H, W), 0.2, np.float32)
    for k in range(4):
        gt[square(2 + 14 * k, 2, 10)] = 255        # four missed movers
        dyn[square(2 + 14 * k, 40, 12)] = 0.8      # four lit-up static squares
    g = gallery_from_evidence(evidence(dyn, gt), max_per_kind=2, min_area=16, open_px=1)
    assert g.counts == {MISSED: 4, FALSE_ALARM: 4}
    assert [(e.region.kind, e.region.rank) for e in g.entries] == [(MISSED, 1), (MISSED, 2), (FALSE_ALARM, 1),
                                                                  (FALSE_ALARM, 2)]
    assert all(e.diagnoses for e in g.entries)


# ----------------------------------------------------------------------------- cues per photo
class _Run:
    """A stand-in for run.SetResult with one photo whose cues are given arrays."""

    def __init__(self, params, dynamic, strips, depth, plane, seen):
        self.params, self.dynamic, self.supports = params, [dynamic], [[1]]
        self.photo_set = type("PS", (), {"photos": [type("Ph", (), {"stem": "ref"})()]})()
        self._cues, self._seen = (strips, depth, plane), seen

    def has_evidence(self, i, s):
        return self._seen

    def strips_log_odds(self, i, s):
        return self._cues[0]

    def sweep_log_odds(self, i, s):
        return self._cues[1]

    def plane_log_odds(self, i, s):
        return self._cues[2]


def test_cue_summary_reads_each_cue_on_the_movers_and_the_static_pixels():
    """Medians per cue over the moving and the static pixels, leaving out what no support saw
    and the don't-care band; a cue the map does not have is NaN; no movers, or the peer
    baseline (no cues), gives no summary."""
    gt = np.zeros((H, W), np.uint8)
    mover = square(10, 10, 20)
    gt[mover] = 255
    gt[square(40, 40, 10)] = 128                       # don't care: in neither median
    strips = np.where(mover, 0.1, 0.5).astype(np.float32)
    depth = np.where(mover, -1.5, 2.5).astype(np.float32)
    depth[square(40, 40, 10)] = -9.0
    seen = np.ones((H, W), bool)
    seen[10:30, 10:15] = False                          # a quarter of the mover unseen (its log-odds 0)
    depth[~seen] = 0.0
    dyn = np.where(mover, 0.8, 0.05).astype(np.float32)
    c = cue_summary(_Run(get_preset("default"), dyn, strips, depth, None, seen), 0, gt)
    assert c.moving["strips"] == pytest.approx(0.1) and c.static["strips"] == pytest.approx(0.5)
    assert c.moving["depth"] == pytest.approx(-1.5) and c.static["depth"] == pytest.approx(2.5)
    assert np.isnan(c.moving["plane"]) and np.isnan(c.static["plane"])
    assert c.dynamic == pytest.approx((0.8, 0.05)) and c.n_moving == 400 and c.n_static == H * W - 400 - 100
    assert c.to_dict()["moving"]["plane"] is None and c.to_dict()["static"]["depth"] == 2.5
    gt_2x = np.kron(gt, np.ones((2, 2), np.uint8))      # ground truth at the original size reads the same
    assert cue_summary(_Run(get_preset("default"), dyn, strips, depth, None, seen), 0, gt_2x).to_dict() == c.to_dict()
    assert cue_summary(_Run(get_preset("default"), dyn, strips, depth, None, seen), 0, np.zeros_like(gt)) is None
    assert cue_summary(_Run(get_preset("peer-homography"), dyn, strips, depth, None, seen), 0, gt) is None
    assert [signed(v) for v in (0.314, -1.2, -0.004, np.nan)] == ["+0.31", "-1.20", "0.00", "–"]


# ----------------------------------------------------------------------------- crowdcam report
def run_cli(*args):
    return subprocess.run([sys.executable, "-m", "crowdcam", *map(str, args)], capture_output=True, text=True,
                          cwd=ROOT, timeout=600)


def test_report_end_to_end(tmp_path):
    """A report of a bundled set at 200 px: report.md / .html / .json with their pictures, each
    entry with a diagnosis and the commands that explain its pixel; a second report reads every
    pair from the cache (the conftest's own cache)."""
    out = tmp_path / "rep"
    r = run_cli("report", SAMPLE_SETS / "tabletop_ball", "--out", out, "--max-side", 200, "--workers", 1, "--quiet")
    assert r.returncode == 0, r.stderr
    assert {p.name for p in out.iterdir()} == {"report.md", "report.html", "report.json", "img"}
    md, page = (out / "report.md").read_text(), (out / "report.html").read_text()
    data = json.loads((out / "report.json").read_text())
    assert data["max_side"] == 200 and len(data["references"]) >= 5
    entries = [e for ref in data["references"] for e in ref["entries"]]
    assert any(e["kind"] == MISSED for e in entries) and entries
    for e in entries:
        assert e["diagnoses"] and e["area_px"] > 0 and (out / e["image"]).is_file()
        assert any("--rr-pixel {},{}".format(*e["pixel"]) in c for c in e["commands"])
    for ref in data["references"]:
        assert (out / "img" / f"{ref['stem']}_map.jpg").is_file() and (out / "img" / f"{ref['stem']}_gt.png").is_file()
    # every picture the pages name exists; the HTML needs nothing from elsewhere
    for src in re.findall(r"\]\((img/[^)]+)\)", md) + re.findall(r'src="([^"]+)"', page):
        assert (out / src).is_file(), src
    assert not re.search(r"(src|href)=\"(https?:)?//", page)
    assert "missed mover" in md and "Jaccard" in md
    # the cues' table: every photo with ground truth and a mover; on these renders the strips and
    # the depth cue (where the photo has cameras) read lower on the movers than on the static pixels
    assert "What each cue says" in md and "What each cue says" in page
    cues = data["cues"]
    assert len(cues) >= 5 and {c["stem"] for c in cues} <= {ref["stem"] for ref in data["references"]}
    assert all(c["moving"]["strips"] < c["static"]["strips"] for c in cues)
    with_depth = [c for c in cues if c["moving"]["depth"] is not None]
    assert with_depth and all(c["moving"]["depth"] < c["static"]["depth"] for c in with_depth)
    assert not list(tmp_path.glob(".rep.*"))
    # again, with a setting of the aggregation changed: every pair from the cache, and the report
    # names the change and carries it into the commands that explain a pixel
    r2 = run_cli("report", SAMPLE_SETS / "tabletop_ball", "--out", out, "--max-side", 200, "--workers", 1,
                 "--param", "aggregate.threshold=0.4")
    assert r2.returncode == 0, r2.stderr
    assert int(re.search(r"(\d+) pairs cached", r2.stderr).group(1)) > 0
    assert "features:" not in r2.stderr and "geometry:" not in r2.stderr      # no progress bar: nothing computed
    data2 = json.loads((out / "report.json").read_text())
    assert data2["changes"] == ["aggregate.threshold=0.4"] and data2["threshold"] == 0.4
    assert "`aggregate.threshold=0.4`" in (out / "report.md").read_text()
    cmds = [c for ref in data2["references"] for e in ref["entries"] for c in e["commands"]]
    assert cmds and all("--param aggregate.threshold=0.4" in c for c in cmds)


def test_the_commands_that_explain_a_pixel_are_ones_the_cli_takes():
    """explain_commands: the inspector and the Rerun recording with the run's size, preset and
    --param changes, each a command line the CLI parses back to them."""
    import shlex

    from crowdcam.cli import build_parser
    from crowdcam.report import explain_commands
    cmds = explain_commands("my set", "cam 01", (12, 34), 320, "paper", ("geometry.affine_tilts=2",))
    for cmd in cmds:
        words = shlex.split(cmd.split("#")[0].split("&&")[0])
        assert words[0] == "crowdcam"
        args = build_parser().parse_args(words[1:])
        assert (args.set, args.max_side, args.preset, args.param) == ("my set", 320, "paper",
                                                                        ["geometry.affine_tilts=2"])
    assert "--rr-ref 'cam 01' --rr-pixel 12,34" in cmds[1]


def test_report_of_a_missing_set_is_one_line_and_writes_nothing(tmp_path):
    out = tmp_path / "rep"
    r = run_cli("report", tmp_path / "nope", "--out", out)
    assert r.returncode == 2
    assert r.stderr.count("\n") == 1 and r.stderr.startswith("crowdcam: error:") and "no such folder" in r.stderr
    assert not out.exists() and list(tmp_path.iterdir()) == []
