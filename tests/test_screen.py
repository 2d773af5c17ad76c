"""The screen of large sets (screen.py): which pairs get full geometry."""

import numpy as np

from pipeline.features import Features
from pipeline.screen import screen_pairs, shared_features, strongest


def _ring_features(n: int, per_photo: int = 60, shared: int = 40, seed: int = 0) -> list[Features]:
    """Photos on a ring: photo i shares `shared` descriptors (with noise) with photo i + 1 and
    fewer with i + 2; nothing with the rest."""
    rng = np.random.default_rng(seed)
    world = rng.normal(size=(n * per_photo, 128)).astype(np.float32)
    feats = []
    for i in range(n):
        own = world[i * per_photo:(i + 1) * per_photo]
        nxt = world[((i + 1) % n) * per_photo:((i + 1) % n) * per_photo + shared]
        prv = world[((i - 1) % n) * per_photo:((i - 1) % n) * per_photo + shared]
        prv2 = world[((i - 2) % n) * per_photo:((i - 2) % n) * per_photo + shared // 3]
        d = np.concatenate([own, nxt, prv, prv2]) + rng.normal(0, 0.05, (per_photo + 2 * shared + shared // 3, 128))
        d = np.abs(d).astype(np.float32)
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        m = len(d)
        feats.append(Features(rng.uniform(0, 100, (m, 2)).astype(np.float32), np.ones(m, np.float32), d,
                              rng.uniform(0, 1, m).astype(np.float32)))
    return feats


def test_shared_features_are_symmetric_and_find_the_neighbours():
    feats = _ring_features(12)
    s = shared_features(feats, 1000, 0.8)
    assert (s == s.T).all() and (np.diag(s) == 0).all()
    for i in range(12):
        order = np.argsort(-s[i])
        assert set(order[:2]) == {(i + 1) % 12, (i - 1) % 12}           # the ring neighbours first
        assert s[i, (i + 6) % 12] <= 2                                      # the far side shares nothing


def _counts_by_definition(feats, n_features, ratio):
    """shared_features by its definition, in numpy: every photo against every other, each way."""
    descs = [strongest(f, n_features) for f in feats]
    n = len(descs)
    count = np.zeros((n, n), np.int32)
    for i in range(n):
        for j in range(n):
            if i == j or len(descs[i]) == 0 or len(descs[j]) == 0:
                continue
            d2 = 2.0 - 2.0 * (descs[i] @ descs[j].T)
            d2 = np.concatenate([d2, np.full((len(d2), 1), np.inf, np.float32)], axis=1)   # no second: passes
            two = np.sort(d2, axis=1)[:, :2]
            count[i, j] = (two[:, 0] < np.float32(ratio * ratio) * two[:, 1]).sum()
    return np.minimum(count, count.T)


def test_shared_features_equal_their_definition_with_photos_of_fewer_keypoints():
    """The compiled pass over each block of products (both directions from one product) counts as
    the plain definition does, also where photos have fewer keypoints than the strongest k (padded)."""
    feats = _ring_features(9, seed=3)
    few = feats[4]
    feats[4] = Features(few.xy[:30], few.size[:30], few.desc[:30], few.response[:30])
    feats[7] = Features(few.xy[:1], few.size[:1], few.desc[:1], few.response[:1])
    for k in (50, 1000):
        got = shared_features(feats, k, 0.8, threads=2)
        assert np.array_equal(got, _counts_by_definition(feats, k, 0.8))
        assert got.sum() > 0


def test_screen_keeps_each_photos_best_partners_and_grows_linearly():
    for n in (12, 24):
        feats = _ring_features(n)
        sc = screen_pairs(shared_features(feats, 1000, 0.8), keep=2)
        assert all(i < j for i, j in sc.pairs)
        assert {(i, (i + 1) % n) if i < (i + 1) % n else ((i + 1) % n, i) for i in range(n)} <= set(sc.pairs)
        assert len(sc.pairs) <= 2 * n                                        # linear, not n(n - 1)/2
        assert "not compared" in sc.reason(0, n // 2, 1000)


def test_strongest_keeps_the_highest_responses():
    f = _ring_features(3)[0]
    d = strongest(f, 10)
    top = np.argsort(-f.response)[:10]
    assert {tuple(r) for r in d.round(5)} == {tuple(r) for r in f.desc[top].round(5)}
    assert len(strongest(Features(f.xy, f.size, f.desc), 10)) == 10       # responses unknown: the first ones


def test_a_screened_set_runs_end_to_end_and_resumes_from_the_cache(tiny_set, tmp_path):
    """8 photos screened as a large set would be (each keeps 2 partners): fewer pairs compared,
    the others rejected as not compared, maps for the photos with supports; a re-run reads the
    screen and the geometry from the cache and gives the same maps."""
    import dataclasses

    from pipeline.cache import PairCache
    from pipeline.loading import load_set
    from pipeline.params import get_preset
    from pipeline.run import detect_set

    p = get_preset("default").replace(max_side=200)
    p = p.replace(geometry=dataclasses.replace(p.geometry, screen_above=4, screen_keep=2))
    cache = PairCache(tmp_path / "cache")
    ps = load_set(tiny_set, p.max_side)
    res = detect_set(ps, p, cache, workers=1)
    n = len(ps.photos)
    skipped = [g for (i, j), g in res.pairs.items() if i < j and g.reason.startswith("not compared")]
    assert 0 < len(skipped) < n * (n - 1) // 2
    assert res.timings["screen_pairs"] <= 2 * n
    assert any(d is not None for d in res.dynamic)
    again = detect_set(load_set(tiny_set, p.max_side), p, cache, workers=1)
    assert again.cache_misses == 0
    for a, b in zip(res.dynamic, again.dynamic):
        assert (a is None and b is None) or np.array_equal(a, b)
