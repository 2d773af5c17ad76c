"""Runs in one process (the inspector's inline runs, one worker)."""

import threading

import numpy as np

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
