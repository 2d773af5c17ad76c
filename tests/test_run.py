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
