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
    sent: list[tuple] = []
    submit = distributed.Client.submit

    def counting_submit(self, func, *args, **kwargs):
        sent.append(args)
        return submit(self, func, *args, **kwargs)

    monkeypatch.setattr(distributed.Client, "submit", counting_submit)
    monkeypatch.setattr(distributed.Client, "scatter", lambda *a, **k: pytest.fail("scattered: a lost worker loses it"))
    view = _view(200)
    with parallel_backend(RunConfig(backend="dask", jobs=2), 2):
        ids = joblib.Parallel(n_jobs=2)(joblib.delayed(Upstream.ids)(view, "objects") for _ in range(12))
    assert ids == [view.ids("objects")] * 12
    assert sum(any(a is view for a in args) for args in sent) == 1


def _ids_or_die(view: Upstream, deaths: str) -> list[str]:
    """The view's ids, after ending this worker's process the first two times any worker runs it."""
    import os

    for n in range(2):
        try:
            os.close(os.open(f"{deaths}.{n}", os.O_CREAT | os.O_EXCL))
        except FileExistsError:
            continue
        os._exit(70)
    return view.ids("objects")


def test_a_view_outlives_every_worker_that_held_it(tmp_path):
    """Both workers die while holding the view (the nannies start new ones): the view is made again from the task
    that holds it, and the call finishes; a scattered view would be forgotten with its last holder."""
    pytest.importorskip("distributed")
    view = _view(200)
    deaths = str(tmp_path / "death")
    with parallel_backend(RunConfig(backend="dask", jobs=2), 2):
        ids = joblib.Parallel(n_jobs=2)(joblib.delayed(_ids_or_die)(view, deaths) for _ in range(6))
    assert ids == [view.ids("objects")] * 6
    assert (tmp_path / "death.1").exists()
