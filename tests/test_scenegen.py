"""The sample-set generator: ground truth, cameras and determinism."""

import json

import cv2
import numpy as np

from crowdcam.scenegen import SETS, ground_truth, write_set


def test_rendered_set_has_movers_cameras_and_boundary_band(tiny_set):
    meta = json.loads((tiny_set / "cameras.json").read_text())
    assert len(meta["cameras"]) == SETS["square_people"].n_cameras
    sizes = set()
    movers = 0
    for cam in meta["cameras"]:
        img = cv2.imread(str(tiny_set / "images" / f"{cam['stem']}.jpg"))
        gt = cv2.imread(str(tiny_set / "gt" / f"{cam['stem']}.png"), cv2.IMREAD_GRAYSCALE)
        assert img.shape[:2] == gt.shape == tuple(cam["size"])
        assert set(np.unique(gt)) <= {0, 128, 255}
        movers += (gt == 255).any()
        if (gt == 255).any():
            assert (gt == 128).any()            # mixed boundary pixels are "don't care"
        sizes.add(tuple(cam["size"]))
    assert movers >= 6 and len(sizes) >= 2     # people in most photos; cameras of different sizes


def test_cameras_project_the_scene_consistently(tiny_set):
    """The centre of the ground (a static point) projects inside most photos, at the same 3-D spot."""
    meta = json.loads((tiny_set / "cameras.json").read_text())
    X = np.array([0.0, 3.0, 0.0])
    inside = 0
    for cam in meta["cameras"]:
        K, R, C = (np.array(cam[k]) for k in ("K", "R", "C"))
        x = K @ R @ (X - C)
        assert x[2] > 0                         # in front of every camera
        u, v = x[:2] / x[2]
        inside += 0 <= u < cam["size"][1] and 0 <= v < cam["size"][0]
    assert inside >= 6


def test_rendering_is_deterministic(tmp_path):
    write_set(SETS["tabletop_ball"], tmp_path / "a", scale=0.15)
    write_set(SETS["tabletop_ball"], tmp_path / "b", scale=0.15)
    for p in sorted((tmp_path / "a").rglob("*.*")):
        assert p.read_bytes() == (tmp_path / "b" / p.relative_to(tmp_path / "a")).read_bytes()


def test_ground_truth_levels():
    cov = np.array([[0.0, 0.5, 1.0]])
    assert ground_truth(cov).tolist() == [[0, 128, 255]]
