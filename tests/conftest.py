"""Shared fixtures: a synthetic camera pair with a known F, and small rendered photo sets."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
SAMPLE_SETS = ROOT / "sample_sets"
sys.path.insert(0, str(ROOT))


def look_at(C, target, f, size, roll=0.0):
    from crowdcam.scenegen import look_at as _look_at
    return _look_at(np.asarray(C, float), np.asarray(target, float), f, size, roll)


def project(cam, X):
    """(N, 3) world points -> (N, 2) pixels."""
    x = (np.asarray(X) - cam.C) @ cam.R.T @ cam.K.T
    return x[:, :2] / x[:, 2:3]


@pytest.fixture(scope="session")
def camera_pair():
    """Two cameras 3 m apart looking at a scene ~8 m away; the true F (x_sup^T F x_ref = 0)."""
    from pipeline.geometry import fundamental_from_cameras
    ref = look_at([0, -8, 1.6], [0, 0, 1.0], 500.0, (480, 640), 0.03)
    sup = look_at([3, -7.5, 2.2], [0.5, 0, 1.0], 560.0, (480, 640), -0.05)
    F = fundamental_from_cameras(ref.P, sup.P)
    rng = np.random.default_rng(0)
    X = np.column_stack([rng.uniform(-4, 4, 200), rng.uniform(-2, 6, 200), rng.uniform(0, 3, 200)])
    return ref, sup, F, X


@pytest.fixture(scope="session")
def tiny_set(tmp_path_factory):
    """The square_people scene rendered at 40 % size (8 photos, about 250 x 190 px)."""
    from crowdcam.scenegen import SETS, write_set
    out = tmp_path_factory.mktemp("sets") / "square_small"
    write_set(SETS["square_people"], out, scale=0.4)
    return out


@pytest.fixture(autouse=True, scope="session")
def _own_cache(tmp_path_factory):
    """No test reads or writes the user's cache (~/.cache/crowdcam): the default cache of every
    test, and of the subprocesses it starts, is a folder of this session's own."""
    import os
    old = os.environ.get("CROWDCAM_CACHE")
    os.environ["CROWDCAM_CACHE"] = str(tmp_path_factory.mktemp("crowdcam-cache"))
    yield
    if old is None:
        os.environ.pop("CROWDCAM_CACHE", None)
    else:
        os.environ["CROWDCAM_CACHE"] = old
