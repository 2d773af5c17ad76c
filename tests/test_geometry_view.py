"""The Geometry view's geometry (inspector/geometry_view.py) on a synthetic camera pair with a
known F: known answers, no browser."""

import numpy as np
import pytest

from conftest import project
from inspector import geometry_view as gv
from pipeline.reconstruction import SetCameras


@pytest.fixture(scope="module")
def pair_cameras(camera_pair):
    """The conftest pair as a SetCameras (photo 0 the reference, 1 the support), and its scene."""
    ref, sup, F, X = camera_pair
    empty = SetCameras.empty(2, "")
    cams = SetCameras(np.ones(2, bool), np.stack([ref.K, sup.K]), np.stack([ref.R, sup.R]), np.stack([ref.C, sup.C]),
                      np.array([[4.0, 14.0], [4.0, 14.0]]), X, np.zeros(len(X), np.float32),
                      np.full((len(X), 3), 128, np.uint8), np.zeros((0, 3), np.int32), np.full((2, 2), 1.5),
                      ("", ""), empty.focal_prior, 0.1, 0.0)
    return cams, ref, sup, F, X


def test_display_frame_is_a_similarity_with_the_cameras_upright(pair_cameras):
    cams = pair_cameras[0]
    frame = gv.display_frame(cams)
    assert np.allclose(frame.rotation @ frame.rotation.T, np.eye(3)) and np.linalg.det(frame.rotation) > 0
    # the median camera lies 1 unit from the centre, and the cameras' mean "down" is +y
    C = frame.points(cams.C)
    assert np.median(np.linalg.norm(C, axis=1)) == pytest.approx(1.0)
    down = np.mean([frame.camera_to_display(R)[:, 1] for R in cams.R], axis=0)
    assert down[1] > 0.99 * np.linalg.norm(down)


def test_a_pixel_on_a_picture_and_back(pair_cameras):
    cams = pair_cameras[0]
    frame = gv.display_frame(cams)
    sizes = [(480, 640), (480, 640)]
    f = gv.frustums(cams, sizes, frame, 0.1, ref=0)[0]
    xy = np.array([[12.0, 30.0], [320.0, 240.0], [630.5, 470.0]])
    P = gv.pixel_on_plane(f, sizes[0], xy)
    eye = f.position + np.array([0.01, -0.02, 0.0])                 # a viewer beside the camera
    for p, want in zip(P, xy):
        assert np.allclose(gv.plane_to_pixel(f, sizes[0], eye, p - eye), want, atol=1e-6)
    assert gv.plane_to_pixel(f, sizes[0], eye, eye - P[1]) is None              # looking away
    # the picture lies where the camera sees the pixel (the principal point is the centre here)
    for p, want in zip(P, xy):
        Xw = p / frame.scale @ frame.rotation + frame.centre
        assert np.allclose(project(pair_cameras[1], Xw[None])[0], want, atol=1e-6)


def test_the_ray_projects_to_the_pixel_and_to_its_epipolar_line(pair_cameras):
    """The viewing ray of a reference pixel projects onto that pixel in the reference and onto its
    epipolar line (from the pair's F) in the support: a point in one photo is a line in another."""
    from pipeline.geometry import epipolar_lines
    from pipeline.support import PairGeometry
    cams, ref, sup, F, X = pair_cameras
    frame = gv.display_frame(cams)
    xy = project(ref, X[:1])[0]
    ray = gv.viewing_ray(cams, frame, 0, xy)
    world = ray / frame.scale @ frame.rotation + frame.centre
    assert np.allclose(world[0], ref.C)
    assert np.allclose(project(ref, world[1:]), xy, atol=1e-6)
    assert cams.depth(0, world[1:2])[0] == pytest.approx(4.0)
    line = epipolar_lines(F, xy[None])[0]
    assert np.abs(np.hstack([project(sup, world[1:]), np.ones((2, 1))]) @ line).max() < 1e-6
    z = np.zeros((0, 2), np.float32)
    g = PairGeometry(0, 1, F, "ok", "", 10, 10, 1.0, 0.0, 0.0, 1.0, z, z, z, z, source="reconstruction",
                     uncertainty_px=1.5)
    (ln,) = gv.support_lines({(0, 1): g}, 0, [1], [(480, 640), (480, 640)], xy)
    assert ln.kind == "epipolar" and ln.colour == gv.uncertainty_colour(1.5)
    assert np.abs(np.hstack([ln.segment, np.ones((2, 1))]) @ line).max() < 1e-3


def test_uncertainty_classes():
    assert gv.uncertainty_colour(0.5) == gv.UNCERTAINTY_CLASSES[0][1]
    assert gv.uncertainty_colour(4.0) == gv.UNCERTAINTY_CLASSES[1][1]
    assert gv.uncertainty_colour(40.0) == gv.UNCERTAINTY_CLASSES[2][1]
    assert gv.uncertainty_colour(float("nan")) == gv.UNKNOWN_RGB
