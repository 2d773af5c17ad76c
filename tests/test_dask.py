"""The per-pair work on a Dask distributed cluster gives the maps of the local process pool, bit
for bit; an address where no scheduler answers is a clear error within 10 s."""

import time

import numpy as np
import pytest

from conftest import SAMPLE_SETS


@pytest.fixture(scope="module")
def cluster():
    from distributed import LocalCluster
    c = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None)
    yield c
    c.close()


def test_dask_equals_the_process_pool(cluster, tmp_path):
    from pipeline.cache import PairCache
    from pipeline.loading import load_set
    from pipeline.params import get_preset
    from pipeline.run import detect_set
    params = get_preset("default").replace(max_side=240)
    ps = load_set(SAMPLE_SETS / "tabletop_ball", params.max_side)
    local = detect_set(ps, params, PairCache(tmp_path / "local"), workers=2)
    cache = PairCache(tmp_path / "dask")
    dist = detect_set(ps, params, cache, scheduler=cluster.scheduler_address)
    assert dist.supports == local.supports
    for a, b in zip(local.dynamic, dist.dynamic):
        assert (a is None) == (b is None)
        if a is not None:
            assert np.abs(a - b).max() == 0
    # the pairs computed on the workers were cached where the client runs
    assert cache.misses > 0 and list((tmp_path / "dask" / "pair").rglob("*.npz"))
    again = detect_set(ps, params, PairCache(tmp_path / "dask"), scheduler=cluster.scheduler_address)
    assert again.cache_misses == 0


def test_a_scheduler_that_does_not_answer(tmp_path):
    from pipeline.cache import PairCache
    from pipeline.loading import load_set
    from pipeline.params import get_preset
    from pipeline.run import SchedulerError, detect_set
    ps = load_set(SAMPLE_SETS / "tabletop_ball", 160)
    t = time.time()
    with pytest.raises(SchedulerError, match="no Dask scheduler answered"):
        detect_set(ps, get_preset("paper").replace(max_side=160), PairCache(None), scheduler="tcp://127.0.0.1:9")
    assert time.time() - t < 15
