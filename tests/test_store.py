"""The pair store keeps memory bounded: evicted results reload from the cache, equal."""

import numpy as np

from conftest import SAMPLE_SETS


def test_evicted_pairs_reload_equal_and_views_freeze(tmp_path):
    from pipeline.cache import PairCache
    from pipeline.loading import load_set
    from pipeline.params import get_preset
    from pipeline.run import detect_set
    from pipeline.store import PairStore
    params = get_preset("paper").replace(max_side=160)
    ps = load_set(SAMPLE_SETS / "tabletop_ball", params.max_side)
    cache = PairCache(tmp_path / "cache")
    store = PairStore(cache, keep=2)
    res = detect_set(ps, params, cache, workers=1, store=store, only_refs=[0, 1])
    assert len(store) > 2 and len(store._mem) == 2           # only two stay in memory
    full = detect_set(ps, params, PairCache(None), workers=1, only_refs=[0, 1])  # no eviction without a cache
    for ij in store:
        a, b = store[ij], full.pair_results[ij]                 # reloaded from the cache
        np.testing.assert_array_equal(a.hog_map, b.hog_map)
        assert store.light(ij).kind == a.kind
    for a, b in zip(res.dynamic, full.dynamic):
        assert (a is None) == (b is None) and (a is None or np.array_equal(a, b))
    view = store.view()
    n = len(view)
    store.put((99, 98), store[next(iter(store))], "x" * 24, lambda d: None)
    assert len(view) == n and (99, 98) not in view and (99, 98) in store
