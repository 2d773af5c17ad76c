"""The `crowdcam` command end to end: outputs, F convention, cache, eval, bad input."""

import hashlib
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from conftest import ROOT, SAMPLE_SETS
from crowdcam.cli import main
from pipeline.geometry import symmetric_epipolar_distance

SET = SAMPLE_SETS / "tabletop_ball"


def run_cli(*args, cache=None):
    cmd = [sys.executable, "-m", "crowdcam", *map(str, args)]
    if cache is not None:
        cmd += ["--cache-dir", str(cache)]
    return subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=600)


def tree_digest(folder: Path) -> str:
    h = hashlib.sha256()
    for p in sorted(folder.rglob("*")):
        h.update(str(p.relative_to(folder)).encode())
        if p.is_file():
            h.update(p.read_bytes())
            h.update(str(p.stat().st_mtime_ns).encode())
    return h.hexdigest()


@pytest.fixture(scope="module")
def detected(tmp_path_factory):
    """One detect run on a bundled set (small working size) shared by the tests below."""
    tmp = tmp_path_factory.mktemp("detect")
    before = tree_digest(SET)
    out, cache = tmp / "out", tmp / "cache"
    r = run_cli("detect", SET, "--out", out, "--max-side", 320, "--quiet", cache=cache)
    assert r.returncode == 0, r.stderr
    return out, cache, before, r


def test_outputs_layout(detected):
    out, _, _, _ = detected
    summary = json.loads((out / "summary.json").read_text())
    cams = json.loads((SET / "cameras.json").read_text())["cameras"]
    for cam in cams:
        if not next(im for im in summary["images"] if im["stem"] == cam["stem"])["has_map"]:
            continue
        h, w = cam["size"]
        m = np.load(out / "maps" / f"{cam['stem']}.npy")
        assert m.dtype == np.float32 and m.shape == (h, w) and 0 <= m.min() and m.max() <= 1
        mask = cv2.imread(str(out / "masks" / f"{cam['stem']}.png"), cv2.IMREAD_UNCHANGED)
        assert mask.shape == (h, w) and set(np.unique(mask)) <= {0, 255}
        assert (mask > 0).sum() == (m > summary["threshold"]).sum()
        assert cv2.imread(str(out / "overlays" / f"{cam['stem']}.jpg")).shape == (h, w, 3)
    assert summary["parameters"]["preset"] == "default"
    assert {"geometry_s", "pairs_s", "total_s"} <= set(summary["timings"])
    p = summary["pairs"][0]
    assert {"ref", "sup", "F", "n_inliers", "status", "reason"} <= set(p)
    assert all(q["reason"] for q in summary["pairs"] if q["status"] != "ok")
    assert not list(out.parent.glob(".out.partial-*"))


def test_fundamental_matrices_follow_the_convention(detected):
    """x_sup^T F x_ref = 0 in original pixels, checked with the renderer's true cameras.

    A wrong convention (F transposed, working-resolution coordinates) is off by tens of pixels
    everywhere; estimation error on admitted pairs is a few pixels."""
    out, _, _, _ = detected
    summary = json.loads((out / "summary.json").read_text())
    cams = {c["stem"]: c for c in json.loads((SET / "cameras.json").read_text())["cameras"]}
    rng = np.random.default_rng(0)
    errs, errs_t = [], []
    for p in summary["pairs"]:
        if p["status"] != "ok":
            continue
        a, b = cams[p["ref"]], cams[p["sup"]]
        Ka, Ra, Ca = (np.array(a[k]) for k in ("K", "R", "C"))
        Kb, Rb, Cb = (np.array(b[k]) for k in ("K", "R", "C"))
        # scene points in front of the reference camera, 1.5-3 m away (the table), seen by both
        x = np.column_stack([rng.uniform(0, a["size"][1], 400), rng.uniform(0, a["size"][0], 400), np.ones(400)])
        X = Ca + (x @ np.linalg.inv(Ka).T @ Ra) * rng.uniform(1.5, 3.0, (400, 1))
        xb = (X - Cb) @ Rb.T @ Kb.T
        xb = xb[:, :2] / xb[:, 2:3]
        vis = (xb[:, 0] >= 0) & (xb[:, 0] < b["size"][1]) & (xb[:, 1] >= 0) & (xb[:, 1] < b["size"][0])
        F = np.array(p["F"])
        errs.append(np.median(symmetric_epipolar_distance(F, x[vis, :2], xb[vis])))
        errs_t.append(np.median(symmetric_epipolar_distance(F.T, x[vis, :2], xb[vis])))
    assert len(errs) >= 3
    diag = np.hypot(*cams[summary["pairs"][0]["ref"]]["size"])
    assert np.median(errs) < 0.01 * diag and min(errs) < 3.0, errs
    assert np.mean(np.array(errs) < np.array(errs_t)) > 0.8


def _ball_lift(out):
    """Median over photos of mean P_dynamic on the ball minus on static pixels."""
    summary = json.loads((out / "summary.json").read_text())
    lifts = []
    for im in summary["images"]:
        if not im["has_map"]:
            continue
        m = np.load(out / "maps" / f"{im['stem']}.npy")
        gt = cv2.imread(str(SET / "gt" / f"{im['stem']}.png"), cv2.IMREAD_GRAYSCALE)
        if (gt == 255).any():
            lifts.append(m[gt == 255].mean() - m[gt == 0].mean())
    return summary["evaluation"], float(np.median(lifts))


def test_moving_ball_stands_out(detected):
    """Quality floor (default preset): the ball stands out and is segmented."""
    ev, lift = _ball_lift(detected[0])
    assert ev["n_with_motion"] >= 5 and ev["mean_opt_image"] > 0.25 and lift > 0.1


def test_paper_preset_quality_floor(detected, tmp_path):
    """The paper's method, unchanged: weaker, but the ball is still above the static scene."""
    _, cache, _, _ = detected
    r = run_cli("detect", SET, "--out", tmp_path / "paper", "--max-side", 320, "--preset", "paper", "--quiet",
                cache=cache)
    assert r.returncode == 0, r.stderr
    ev, lift = _ball_lift(tmp_path / "paper")
    assert json.loads((tmp_path / "paper" / "summary.json").read_text())["preset"] == "paper"
    assert ev["mean_opt_image"] > 0.05 and lift > 0.03


def test_input_is_untouched_and_cache_is_reused(detected, tmp_path):
    out, cache, before, _ = detected
    assert tree_digest(SET) == before
    r = run_cli("detect", SET, "--out", tmp_path / "again", "--max-side", 320, cache=cache)
    assert r.returncode == 0, r.stderr
    s1 = json.loads((out / "summary.json").read_text())
    s2 = json.loads((tmp_path / "again" / "summary.json").read_text())
    assert s2["cache"]["misses"] == 0 and s2["cache"]["hits"] > 0
    for im in s1["images"]:
        if im["has_map"]:
            assert np.array_equal(np.load(out / "maps" / f"{im['stem']}.npy"),
                                  np.load(tmp_path / "again" / "maps" / f"{im['stem']}.npy"))


def test_eval_prints_the_table_row(detected):
    out, _, _, _ = detected
    r = run_cli("eval", out)
    assert r.returncode == 0, r.stderr
    assert "Jaccard opt. per image" in r.stdout and "opt. per set" in r.stdout
    res = json.loads((out / "eval.json").read_text())
    assert 0 <= res["mean_opt_set"] <= res["mean_opt_image"] <= 1


def _noise_images(folder: Path, n: int, seed: int = 0):
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    for i in range(n):
        cv2.imwrite(str(folder / f"n{i}.png"), (rng.random((96, 128, 3)) * 255).astype(np.uint8))


@pytest.mark.parametrize("case,expect", [
    ("missing", "no such folder"),
    ("empty", "no images found"),
    ("one_image", "fewer than two usable images"),
    ("no_geometry", "no pair of photos has trustworthy geometry"),
    ("out_inside_input", "must not be inside the input folder"),
])
def test_bad_input_gives_one_line_error(tmp_path, case, expect):
    d = tmp_path / "set"
    args = ["detect", d, "--workers", "1", "--no-cache"]
    if case == "empty":
        d.mkdir()
    elif case == "one_image":
        shutil.copytree(SET / "images", d)
        for p in sorted(d.iterdir())[1:]:
            p.write_bytes(b"corrupt")
    elif case == "no_geometry":
        _noise_images(d, 3)
    elif case == "out_inside_input":
        shutil.copytree(SET / "images", d)
        args += ["--out", d / "results"]
    out_default = tmp_path / "crowdcam-out"
    r = subprocess.run([sys.executable, "-m", "crowdcam", *map(str, args)], capture_output=True, text=True,
                       cwd=tmp_path, timeout=300)
    assert r.returncode == 2
    lines = [l for l in r.stderr.splitlines() if l.startswith("crowdcam: error")]
    assert len(lines) == 1 and expect in lines[0], r.stderr
    assert "Traceback" not in r.stderr
    assert not out_default.exists() and not (d / "results").exists()


def test_a_setting_changed_by_name_reaches_the_run_and_its_summary(detected, tmp_path):
    _, cache, _, _ = detected
    out = tmp_path / "out"
    r = run_cli("detect", SET, "--out", out, "--max-side", 320, "--quiet", "--param", "sweep.min_agree=2",
                "--param", "geometry.recon_rescue_planar=false", cache=cache)
    assert r.returncode == 0, r.stderr
    params = json.loads((out / "summary.json").read_text())["parameters"]
    assert params["sweep"]["min_agree"] == 2 and params["geometry"]["recon_rescue_planar"] is False
    bad = run_cli("detect", SET, "--out", tmp_path / "bad", "--param", "sweep.nope=1", cache=cache)
    lines = [l for l in bad.stderr.splitlines() if l.startswith("crowdcam: error")]
    assert bad.returncode == 2 and len(lines) == 1 and "no field 'nope' in sweep" in lines[0], bad.stderr
    assert "Traceback" not in bad.stderr and not (tmp_path / "bad").exists()
    bad = run_cli("inspect", SET, "--port", 0, "--param", "sweep.nope=1", cache=cache)       # before it serves
    lines = [l for l in bad.stderr.splitlines() if l.startswith("crowdcam: error")]
    assert bad.returncode == 2 and len(lines) == 1 and "no field 'nope' in sweep" in lines[0], bad.stderr


def test_empty_masks_are_named_and_summed_up_once(detected, tmp_path):
    """A threshold no pixel passes: each photo's warning gives its map's range, and one line for
    the set says how many masks are empty and where the maps peak."""
    _, cache, _, _ = detected
    r = run_cli("detect", SET, "--out", tmp_path / "out", "--max-side", 320, "--threshold", 1.0, cache=cache)
    assert r.returncode == 0, r.stderr
    per_photo = [l for l in r.stderr.splitlines() if "no pixel above the threshold 1" in l]
    summary = [l for l in r.stderr.splitlines() if "masks are empty at 1;" in l]
    n = len(json.loads((tmp_path / "out" / "summary.json").read_text())["images"])
    assert len(per_photo) > 1 and len(summary) == 1, r.stderr
    assert f"{len(per_photo)} of " in summary[0] and "--threshold" in summary[0]
    assert len(per_photo) <= n


def test_warnings_name_the_skipped_files(tmp_path):
    d = tmp_path / "set"
    shutil.copytree(SET / "images", d)
    (d / "readme.txt").write_text("not a photo")
    (d / "zz_broken.jpg").write_bytes(b"\xff\xd8 broken")
    r = run_cli("detect", d, "--out", tmp_path / "out", "--max-side", 200, "--no-cache")
    assert r.returncode == 0, r.stderr
    assert "readme.txt: skipped" in r.stderr and "zz_broken.jpg: not a readable image" in r.stderr


def test_failed_write_leaves_no_partial_output(tmp_path, monkeypatch):
    import pipeline.output as output
    d = tmp_path / "set"
    shutil.copytree(SET / "images", d)
    calls = {"n": 0}
    real = output.heat_overlay

    def flaky(*a, **k):
        calls["n"] += 1
        if calls["n"] == 2:          # after the first photo's files are written
            raise OSError(28, "No space left on device")
        return real(*a, **k)
    monkeypatch.setattr(output, "heat_overlay", flaky)
    rc = main(["detect", str(d), "--out", str(tmp_path / "out"), "--max-side", "240", "--workers", "1",
               "--no-cache", "--quiet"])
    assert rc == 3                   # the machine failed, not the input (README: exit codes)
    assert not (tmp_path / "out").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".out.")]


def test_huge_photo_is_downscaled(tmp_path):
    """A 6000x4000 phone photo works: maps come back at full size."""
    d = tmp_path / "set"
    d.mkdir()
    imgs = sorted((SET / "images").iterdir())[:3]
    for k, p in enumerate(imgs):
        img = cv2.imread(str(p))
        if k == 0:
            img = cv2.resize(img, (6000, 4000), interpolation=cv2.INTER_LINEAR)
        cv2.imwrite(str(d / p.name), img, [cv2.IMWRITE_JPEG_QUALITY, 80])
    r = run_cli("detect", d, "--out", tmp_path / "out", "--max-side", 240, "--no-cache", "--workers", "1")
    assert r.returncode == 0, r.stderr
    s = json.loads((tmp_path / "out" / "summary.json").read_text())
    big = s["images"][0]
    assert big["size"] == [4000, 6000] and max(big["working_size"]) == 240
    if big["has_map"]:
        assert np.load(tmp_path / "out" / "maps" / f"{big['stem']}.npy", mmap_mode="r").shape == (4000, 6000)


def test_planar_set_needs_the_default_preset(tmp_path):
    """Shots of a flat scene from one spot: every F is degenerate. The paper preset stops with a
    clear error; the default preset uses them as homography pairs and finds the moved object."""
    from test_homography import _scene
    d = tmp_path / "flat"
    (d / "images").mkdir(parents=True)
    (d / "gt").mkdir()
    base = _scene(5, 360, 480)
    for k in range(4):
        H = np.eye(3) + np.diag([0.02, -0.02, 0]) * (k - 1.5) + np.array([[0, 0, 8.0 * k], [0, 0, -5.0 * k], [0, 0, 0]])
        img = cv2.warpPerspective(base, H, (480, 360), borderMode=cv2.BORDER_REFLECT)
        x, y = 60 + 90 * k, 150 + 10 * k                        # a square that moves between shots
        cv2.rectangle(img, (x, y), (x + 60, y + 60), (30, 30, 220), -1)
        gt = np.zeros((360, 480), np.uint8)
        gt[y:y + 61, x:x + 61] = 255
        cv2.imwrite(str(d / "images" / f"v{k}.jpg"), img)
        cv2.imwrite(str(d / "gt" / f"v{k}.png"), gt)
    r = run_cli("detect", d, "--out", tmp_path / "paper", "--no-cache", "--workers", 1, "--preset", "paper")
    assert r.returncode == 2 and "no pair of photos has trustworthy geometry" in r.stderr
    r = run_cli("detect", d, "--out", tmp_path / "default", "--preset", "default", "--no-cache", "--workers", 1)
    assert r.returncode == 0, r.stderr
    s = json.loads((tmp_path / "default" / "summary.json").read_text())
    assert {p["status"] for p in s["pairs"]} == {"homography"}
    assert s["evaluation"]["mean_opt_image"] > 0.5


@pytest.mark.parametrize("case", ["missing", "garbage"])
def test_view_rejects_bad_recordings(tmp_path, case):
    f = tmp_path / "x.rrd"
    if case == "garbage":
        f.write_bytes(b"not a recording")
    r = run_cli("view", f)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and str(f) in r.stderr


def test_rrd_is_written_atomically_and_only_when_asked(tmp_path, detected):
    _, cache, _, _ = detected
    rrd = tmp_path / "sub" / "run.rrd"
    r = run_cli("detect", SET, "--out", tmp_path / "out", "--max-side", 240, "--rrd", rrd, "--quiet", cache=cache)
    assert r.returncode == 0, r.stderr
    assert rrd.stat().st_size > 100_000 and not list(rrd.parent.glob(".*partial"))
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["rerun_s"] > 0
    assert "rerun_s" not in json.loads((detected[0] / "summary.json").read_text())


def test_live_serving_with_a_recording_publishes_the_file_when_it_ends(tmp_path, detected):
    """--rerun-web with --rrd: while serving, no half-written file is in place; after Ctrl-C the
    recording is complete and readable, and nothing is left running."""
    import re
    import signal

    from pipeline.rerun_log import read_blueprint_desc
    _, cache, _, _ = detected
    rrd = tmp_path / "live.rrd"
    proc = subprocess.Popen([sys.executable, "-m", "crowdcam", "detect", str(SET), "--out", str(tmp_path / "out"),
                             "--max-side", "240", "--rerun-web", "--rrd", str(rrd), "--quiet", "--cache-dir",
                             str(cache)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    line = proc.stdout.readline()
    port = re.search(r"127\.0\.0\.1:(\d+)/", line)
    assert port, line + proc.stderr.read()
    assert not rrd.exists()
    proc.send_signal(signal.SIGINT)
    assert proc.wait(timeout=30) == 0
    assert read_blueprint_desc(rrd)["focus"]
    # the viewer dies with its parent (PR_SET_PDEATHSIG); on a loaded machine that takes a moment
    for _ in range(50):
        left = subprocess.run(["pgrep", "-f", f"rerun --serve-web.*{port.group(1)}"], capture_output=True, text=True)
        if left.stdout.strip() == "":
            break
        time.sleep(0.2)
    assert left.stdout.strip() == ""


def test_inspect_serves_until_interrupted(tmp_path, detected):
    """`crowdcam inspect SET` as a user runs it: prints its loopback URL, serves the page, stops on
    Ctrl-C with exit 0, and writes nothing until asked."""
    import re
    import signal
    import urllib.request
    _, cache, _, _ = detected
    proc = subprocess.Popen([sys.executable, "-m", "crowdcam", "inspect", str(SET), "--port", "0", "--max-side", "240",
                             "--out", str(tmp_path / "out"), "--cache-dir", str(cache)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        url = None
        for _ in range(20):
            line = proc.stdout.readline()
            m = re.search(r"crowdcam inspector: (http://127\.0\.0\.1:\d+/)", line)
            if m:
                url = m.group(1)
                break
        assert url, proc.stderr.read()
        assert b"<html" in urllib.request.urlopen(url, timeout=10).read(2000).lower()
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=30) == 0
        assert "Traceback" not in proc.stderr.read()
        assert not (tmp_path / "out").exists()
    finally:
        if proc.poll() is None:
            proc.kill()


@pytest.mark.parametrize("args,expect", [
    (["/no/such/set"], "no such"),
    ([str(SET), "--port", "70000"], "--port"),
    ([str(SET), "--host", "999.1.1.1"], "--host"),
    ([str(SET), "--out", str(SET / "inspector")], "must not be inside"),
])
def test_inspect_bad_input_gives_one_line_error(args, expect):
    r = run_cli("inspect", *args)
    assert r.returncode == 2
    assert r.stderr.count("\n") == 1 and expect in r.stderr and "Traceback" not in r.stderr


def test_bench_caps_the_supports_and_compares_dask_with_the_pool(tmp_path):
    out = tmp_path / "bench.json"
    r = run_cli("bench", SET, "--preset", "paper", "--max-side", 160, "--max-supports", 1, "--dask", 1,
                "--json", out, "--quiet")
    assert r.returncode == 0, r.stdout + r.stderr
    row = json.loads(out.read_text())["rows"][0]
    assert row["max_supports"] == 1 and 0 < row["ordered_pairs"] <= row["images"]   # one support a photo at most
    assert 0 < row["pair_stage_s_per_pair"] <= row["s_per_pair"]
    if row.get("has_motion"):       # the masks as written score no better than at the best threshold
        assert row["mask_threshold"] == 0.5 and 0 <= row["jaccard_at_mask"] <= row["jaccard_opt_set"] + 1e-9
    dask = row["dask"]
    assert dask["workers"] == 1 and dask["same_photos_mapped"] and dask["max_abs_diff"] == 0
    assert "Dask, LocalCluster of 1 worker process:" in r.stdout
    for bad, expect in ((("--dask", 0), "--dask 0"), (("--max-supports", -1), "--max-supports must be")):
        b = run_cli("bench", SET, *bad, "--json", tmp_path / "no.json")
        assert b.returncode == 2 and expect in b.stderr and "Traceback" not in b.stderr, b.stderr
        assert not (tmp_path / "no.json").exists()
