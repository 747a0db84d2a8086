"""What a stage sees of its upstream stages: the :class:`~pipeline.stage.Upstream` view as it travels to workers."""

from __future__ import annotations

import pickle
from pathlib import Path

import joblib
import pytest

from pipeline.backends import parallel_backend
from pipeline.config import RunConfig
from pipeline.stage import Upstream
from pipeline.store import Entry


def _view(n: int) -> Upstream:
    entries = {f"o{i:04d}": Entry(key=f"{i:064x}", task=f"o{i:04d}", status="ok", file=f"o{i:04d}.h5",
                                  meta={"rows": i}) for i in range(n)}
    return Upstream(Path("/nowhere"), {"objects": entries})


def test_sizeof_grows_with_the_entries_like_the_pickled_view():
    sizeof = pytest.importorskip("dask.sizeof").sizeof
    small, large = _view(10), _view(1000)
    assert sizeof(large) > 1e3  # joblib's dask backend scatters an argument over 1 kB
    ratio = sizeof(large) / len(pickle.dumps(large))
    assert 0.25 < ratio < 4.0
    assert sizeof(large) - sizeof(small) == pytest.approx(99 * (sizeof(small) - sizeof(_view(0))), rel=0.01)


def test_one_view_is_sent_to_a_dask_cluster_once_for_all_its_tasks(monkeypatch):
    """Without a size dask can see, the view was pickled into every task and passed through the dask scheduler."""
    distributed = pytest.importorskip("distributed")
    scattered: list[object] = []
    scatter = distributed.Client.scatter

    def counting_scatter(self, data, *args, **kwargs):
        scattered.append(data)
        return scatter(self, data, *args, **kwargs)

    monkeypatch.setattr(distributed.Client, "scatter", counting_scatter)
    view = _view(200)
    with parallel_backend(RunConfig(backend="dask", jobs=2), 2):
        ids = joblib.Parallel(n_jobs=2)(joblib.delayed(Upstream.ids)(view, "objects") for _ in range(12))
    assert ids == [view.ids("objects")] * 12
    assert scattered == [view]
