"""The engine on a toy pipeline: keys, skipping, failures, staleness, determinism across workers, locking."""

from __future__ import annotations

import dataclasses
import gc
import json

import pytest

from pipeline import worker
from pipeline.config import load_config
from pipeline.errors import GenError, LockError, StageError
from pipeline.keys import sha256_file
from pipeline.repro import shard_hashes
from pipeline.scheduler import run_pipeline
from pipeline.stage import Task, topological_order
from pipeline.status import status
from pipeline.store import Manifest, RunLock, stage_dir
from pipeline.worker import DiskFullError, return_freed_memory
from tests.toy_stages import CRASHY, TOY, WARN_TOY, CheckedSums, CrashConfig, read_json, write_json


def config(out, *sets):
    return load_config(TOY.schema, None, [f"run.out={out}", *sets])


def by_stage(reports):
    return {r.stage: r for r in reports}


def test_order_puts_inputs_first_and_limits_to_targets():
    assert [s.name for s in topological_order(TOY.stages)] == ["numbers", "sums"]
    assert [s.name for s in topological_order(TOY.stages, ["numbers"])] == ["numbers"]
    with pytest.raises(StageError, match="unknown stage 'nope'; choose one of: sums, numbers"):
        topological_order(TOY.stages, ["nope"])


def test_second_run_skips_everything(tmp_path):
    cfg = config(tmp_path / "out", "run.jobs=1")
    first = by_stage(run_pipeline(TOY, cfg))
    assert (first["numbers"].ran, first["sums"].ran) == (4, 1)
    second = by_stage(run_pipeline(TOY, cfg))
    assert (second["numbers"].ran, second["numbers"].skipped) == (0, 4)
    assert (second["sums"].ran, second["sums"].skipped) == (0, 1)


def test_same_bytes_for_one_and_two_workers(tmp_path):
    run_pipeline(TOY, config(tmp_path / "a", "run.jobs=1"))
    run_pipeline(TOY, config(tmp_path / "b", "run.jobs=2"))
    a, b = shard_hashes(tmp_path / "a"), shard_hashes(tmp_path / "b")
    assert len(a) == 5 and a == b


def test_each_task_gets_its_own_rng(tmp_path):
    run_pipeline(TOY, config(tmp_path / "o", "run.jobs=1"))
    hashes = shard_hashes(tmp_path / "o")
    assert len({hashes[f"numbers/{i}"] for i in "abcd"}) == 4
    entries = Manifest(stage_dir(tmp_path / "o", "numbers")).entries().values()
    draws = [read_json(stage_dir(tmp_path / "o", "numbers") / e.file)["x"] for e in entries]
    assert len({tuple(d) for d in draws}) == 4


def test_costly_tasks_start_first_and_cost_stays_out_of_the_key(tmp_path):
    import dataclasses

    from pipeline.plan import plan
    from pipeline.stage import Upstream

    run_pipeline(TOY, config(tmp_path / "o", "run.jobs=1", "numbers.ids=[a, ccc, bb, dddd, e]"))
    lines = (stage_dir(tmp_path / "o", "numbers") / "manifest.jsonl").read_text().splitlines()
    assert [json.loads(line)["task"] for line in lines] == ["dddd", "ccc", "bb", "a", "e"]

    stage = next(s for s in TOY.stages if s.name == "numbers")
    params = TOY.schema().numbers
    free = type(stage)()
    free.tasks = lambda p, u: [dataclasses.replace(t, cost=0.0) for t in type(stage).tasks(stage, p, u)]
    empty = Upstream(tmp_path / "o", {})
    assert [p.key for p in plan(stage, params, empty)] == [p.key for p in plan(free, params, empty)]


def test_changed_param_reruns_that_stage_and_downstream_only(tmp_path):
    out = tmp_path / "o"
    run_pipeline(TOY, config(out, "run.jobs=1"))
    reports = by_stage(run_pipeline(TOY, config(out, "run.jobs=1", "sums.scale=2")))
    assert reports["numbers"].ran == 0 and reports["sums"].ran == 1
    reports = by_stage(run_pipeline(TOY, config(out, "run.jobs=1", "numbers.size=6", "sums.scale=2")))
    assert reports["numbers"].ran == 4 and reports["sums"].ran == 1


def test_going_back_to_old_params_reuses_old_shards(tmp_path):
    out = tmp_path / "o"
    run_pipeline(TOY, config(out, "run.jobs=1"))
    before = json.loads((stage_dir(out, "sums") / "manifest.jsonl").read_text().splitlines()[0])
    run_pipeline(TOY, config(out, "run.jobs=1", "numbers.size=7"))
    reports = by_stage(run_pipeline(TOY, config(out, "run.jobs=1")))
    assert reports["numbers"].ran == 0 and reports["sums"].ran == 0
    # and downstream reads the current upstream shards, not the newest ones
    assert reports["sums"].skipped == 1 and before["status"] == "ok"


def test_input_file_bytes_enter_the_key(tmp_path):
    data = tmp_path / "input.txt"
    data.write_text("one")
    cfg = config(tmp_path / "o", "run.jobs=1", f"numbers.input_file={data}")
    run_pipeline(TOY, cfg)
    data.write_text("two")
    assert by_stage(run_pipeline(TOY, cfg))["numbers"].ran == 4
    st = {s.stage: s for s in status(TOY, cfg)}
    assert st["numbers"].state == "done"


def test_failed_task_is_recorded_and_the_rest_goes_on(tmp_path):
    cfg = config(tmp_path / "o", "run.jobs=2", "numbers.ids=[a, bad1, b]")
    reports = by_stage(run_pipeline(TOY, cfg))
    assert (reports["numbers"].ran, reports["numbers"].failed) == (2, 1)
    assert reports["numbers"].failures == [("bad1", "InputError: bad1: this input is broken on purpose")]
    assert reports["sums"].ran == 1  # downstream runs on what succeeded
    again = by_stage(run_pipeline(TOY, cfg))
    assert (again["numbers"].ran, again["numbers"].failed) == (0, 1)  # remembered, not retried
    retried = by_stage(run_pipeline(TOY, cfg, retry_failed=True))
    assert (retried["numbers"].ran, retried["numbers"].failed) == (0, 1)
    st = {s.stage: s for s in status(TOY, cfg)}
    assert st["numbers"].state == "failed" and st["numbers"].failed == 1


def test_a_worker_process_that_dies_stops_the_run_in_one_line_and_the_rest_resumes(tmp_path):
    """A task that ends its loky worker (as a segfault or the OOM killer would): one line naming the stage, the
    finished tasks committed, and the same run without that task does only the rest."""
    out = tmp_path / "o"
    sets = [f"run.out={out}", "run.jobs=2", "numbers.ids=[a, b, c, d, crash]", f"numbers.crash_once={tmp_path / 'x'}"]
    cfg = load_config(CrashConfig, None, sets)
    with pytest.raises(GenError, match=r"^numbers: a worker process died \(exit .*70.*\) while running one of \d "
                                       r"unfinished tasks: .* run the same command again to resume$"):
        run_pipeline(CRASHY, cfg)
    finished = len(Manifest(stage_dir(out, "numbers")).entries(compact=True))
    again = by_stage(run_pipeline(CRASHY, cfg))
    assert (again["numbers"].ran, again["numbers"].skipped, again["numbers"].failed) == (5 - finished, finished, 0)


def test_a_task_s_cpu_seconds_count_the_child_processes_it_waited_for(tmp_path):
    """The objects stage runs CoACD in a child process; its CPU is the task's."""
    out = tmp_path / "o"
    run_pipeline(CRASHY, load_config(CrashConfig, None, [f"run.out={out}", "run.jobs=1", "numbers.ids=[child, a]"]))
    cpu = {e.task: e.cpu_seconds for e in Manifest(stage_dir(out, "numbers")).entries().values()}
    assert cpu["child"] >= 0.3 > cpu["a"]


def test_shard_without_manifest_entry_does_not_exist(tmp_path):
    out = tmp_path / "o"
    cfg = config(out, "run.jobs=1")
    run_pipeline(TOY, cfg)
    manifest = stage_dir(out, "numbers") / "manifest.jsonl"
    lines = manifest.read_text().splitlines()
    # As if killed after writing the last shard but before committing it, mid-way through the line.
    manifest.write_text("\n".join(lines[:-1]) + "\n" + lines[-1][:40])
    reports = by_stage(run_pipeline(TOY, cfg))
    assert reports["numbers"].ran == 1 and reports["numbers"].skipped == 3


def test_damaged_shard_is_redone(tmp_path):
    out = tmp_path / "o"
    cfg = config(out, "run.jobs=1")
    run_pipeline(TOY, cfg)
    entry = next(iter(Manifest(stage_dir(out, "numbers")).entries().values()))
    path = stage_dir(out, "numbers") / entry.file
    path.write_bytes(path.read_bytes()[:-1] + b"\x00")
    assert by_stage(run_pipeline(TOY, cfg))["numbers"].ran == 1
    assert sha256_file(path) == entry.sha256


def test_status_says_why_a_stage_is_stale(tmp_path):
    out = tmp_path / "o"
    run_pipeline(TOY, config(out, "run.jobs=1"))
    st = {s.stage: s for s in status(TOY, config(out, "sums.scale=3"))}
    assert st["numbers"].state == "done" and st["numbers"].done == 4
    assert st["sums"].state == "stale" and st["sums"].reasons == ["1 task(s): its params changed"]
    st = {s.stage: s for s in status(TOY, config(out, "numbers.size=9"))}
    assert st["numbers"].state == "stale" and "its params changed" in st["numbers"].reasons[0]
    assert st["sums"].state == "waiting"
    st = {s.stage: s for s in status(TOY, config(tmp_path / "empty"))}
    assert st["numbers"].state == "missing" and st["numbers"].missing == 4


def test_lock_stops_a_second_writer(tmp_path):
    out = tmp_path / "o"
    with RunLock(out):
        with pytest.raises(LockError, match="another run is writing this output folder"):
            run_pipeline(TOY, config(out))
    run_pipeline(TOY, config(out, "run.jobs=1"))  # released


def test_dask_backend_gives_the_same_bytes(tmp_path):
    pytest.importorskip("dask.distributed")
    run_pipeline(TOY, config(tmp_path / "a", "run.jobs=1"))
    run_pipeline(TOY, config(tmp_path / "d", "run.jobs=2", "run.backend=dask"))
    assert shard_hashes(tmp_path / "a") == shard_hashes(tmp_path / "d")


def test_ray_backend_gives_the_same_bytes(tmp_path):
    """Only where the optional ray extra is installed (``pip install -e '.[ray]'``); CI has dask, not ray."""
    pytest.importorskip("ray")
    run_pipeline(TOY, config(tmp_path / "a", "run.jobs=1"))
    run_pipeline(TOY, config(tmp_path / "r", "run.jobs=2", "run.backend=ray"))
    assert shard_hashes(tmp_path / "a") == shard_hashes(tmp_path / "r")


def test_publish_runs_after_the_stage_with_its_current_shards(tmp_path):
    out = tmp_path / "o"
    run_pipeline(TOY, config(out, "run.jobs=1", "sums.scale=2"))
    (entry,) = Manifest(stage_dir(out, "sums")).entries().values()
    total = float(read_json(stage_dir(out, "sums") / entry.file)["total"])
    assert (out / "published" / "total.txt").read_text() == f"{total!r} from 4 shards\n"
    run_pipeline(TOY, config(out, "run.jobs=1", "sums.scale=3"))
    assert (out / "published" / "total.txt").read_text() == f"{total / 2 * 3!r} from 4 shards\n"


def test_backends_without_streaming_get_the_calls_in_chunks(monkeypatch):
    """Joblib's ray backend cannot stream results; the multiprocessing backend stands in for it here."""
    import joblib

    from pipeline import scheduler

    batches = []
    real = joblib.Parallel

    class Counting(real):
        def __call__(self, iterable):
            batch = list(iterable)
            batches.append((len(batch), self.return_as))
            return super().__call__(batch)

    monkeypatch.setattr(scheduler.joblib, "Parallel", Counting)
    calls = [joblib.delayed(abs)(-i) for i in range(19)]
    with joblib.parallel_config(backend="multiprocessing"):
        assert sorted(scheduler._finished(calls, 2)) == list(range(19))
    assert batches == [(8, "list"), (8, "list"), (3, "list")]
    batches.clear()
    with joblib.parallel_config(backend="loky"):
        assert sorted(scheduler._finished(calls, 2)) == list(range(19))
    assert batches == [(19, "generator_unordered")]


class _Squares(TOY.stage("sums").__class__):
    """A second reader of ``numbers``, independent of ``sums``: both share a wave."""

    name = "squares"
    ext = "json"

    def params(self, config):
        return config.sums

    def tasks(self, params, upstream):
        return [Task(id=f"sq_{i}", needs={"numbers": [i]}, cost=1.0) for i in upstream.ids("numbers")]

    def run(self, task, params, upstream, rng, out, ctx):
        x = read_json(upstream.path("numbers", task.needs["numbers"][0]))["x"]
        write_json(out, {"x2": [v * v for v in x]})
        return {}

    def publish(self, params, shards, dest):
        (dest / "squares.txt").write_text(f"{len(shards.ids('squares'))} squared\n")


def test_independent_stages_share_a_wave_and_give_the_same_bytes(tmp_path):
    import dataclasses

    from pipeline.stage import stage_waves

    project = dataclasses.replace(TOY, stages=(*TOY.stages, _Squares()))
    assert [[s.name for s in w] for w in stage_waves(topological_order(project.stages))] == [
        ["numbers"],
        ["sums", "squares"],
    ]
    assert [[s.name for s in w] for w in stage_waves(topological_order(project.stages, ["sums"]))] == [
        ["numbers"],
        ["sums"],
    ]
    events = []
    together = run_pipeline(project, config(tmp_path / "w", "run.jobs=2"), progress=lambda e, **i: events.append(
        (e, i["stage"])))
    assert [r.stage for r in together] == ["numbers", "sums", "squares"]
    assert {r.stage: r.ran for r in together} == {"numbers": 4, "sums": 1, "squares": 4}
    assert (tmp_path / "w" / "squares.txt").read_text() == "4 squared\n"
    assert (tmp_path / "w" / "published" / "total.txt").exists()
    # both stages of the wave start before either ends
    starts = [i for i, (e, s) in enumerate(events) if e == "stage_start" and s in ("sums", "squares")]
    ends = [i for i, (e, s) in enumerate(events) if e == "stage_end" and s in ("sums", "squares")]
    assert max(starts) < min(ends)
    # one stage at a time (by targets) gives the same shards
    run_pipeline(project, config(tmp_path / "s", "run.jobs=1"), targets=["sums"])
    run_pipeline(project, config(tmp_path / "s", "run.jobs=1"), targets=["squares"])
    assert shard_hashes(tmp_path / "w") == shard_hashes(tmp_path / "s")


def test_a_full_disk_stops_the_run_and_a_resume_after_freeing_space_gives_the_same_bytes(tmp_path):
    full = tmp_path / "disk_is_full"
    full.touch()
    cfg = config(tmp_path / "o", "run.jobs=1", f"numbers.disk_full_while={full}")
    with pytest.raises(DiskFullError, match=r"numbers/\w+: No space left on device while writing .*run the same"):
        run_pipeline(TOY, cfg)
    numbers = stage_dir(tmp_path / "o", "numbers")
    assert not [p for p in numbers.rglob("*") if p.is_file() and p.name != "manifest.jsonl"]  # no partial shard
    assert Manifest(numbers).entries() == {}  # nothing remembered as failed
    full.unlink()  # space freed
    reports = by_stage(run_pipeline(TOY, cfg))
    assert reports["numbers"].ran == 4 and reports["numbers"].failed == 0
    reference = tmp_path / "ref"
    run_pipeline(TOY, config(reference, "run.jobs=1", f"numbers.disk_full_while={full}"))
    assert shard_hashes(tmp_path / "o") == shard_hashes(reference)


# --------------------------------------------------------------------------------------------------------------
# Status checks shards as the run does; warnings; the published output's check and repair (WARN_TOY, in
# tests/toy_stages.py).


def flip_byte(path):
    """Change one byte in the middle of ``path`` in place (same size, same inode: through every hard link)."""
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x01
    with open(path, "r+b") as f:
        f.write(data)


def test_status_checks_shards_as_the_run_does_and_plans_below_a_damaged_one(tmp_path):
    out = tmp_path / "o"
    cfg = config(out, "run.jobs=1")
    run_pipeline(TOY, cfg)
    assert [s.state for s in status(TOY, cfg)] == ["done", "done"]
    (entry,) = [e for e in Manifest(stage_dir(out, "numbers")).entries().values() if e.task == "b"]
    flip_byte(stage_dir(out, "numbers") / entry.file)
    st = {s.stage: s for s in status(TOY, cfg)}
    assert (st["numbers"].state, st["numbers"].done, st["numbers"].missing) == ("missing", 3, 1)
    assert st["numbers"].reasons == ["1 task(s): its shard is missing or damaged (b)"]
    # the run remakes b with the same key, so sums keeps its key: done, not waiting
    assert (st["sums"].state, st["sums"].done) == ("done", 1)
    reports = by_stage(run_pipeline(TOY, cfg))
    assert (reports["numbers"].ran, reports["numbers"].skipped) == (1, 3)
    assert (reports["sums"].ran, reports["sums"].skipped) == (0, 1)
    assert sha256_file(stage_dir(out, "numbers") / entry.file) == entry.sha256
    assert [s.state for s in status(TOY, cfg)] == ["done", "done"]


def test_warnings_of_planning_and_tasks_reach_the_report_and_publish(tmp_path):
    cfg = config(tmp_path / "o", "run.jobs=2", "numbers.ids=[a, w1, b, c, x9]")
    expected = [
        "left out x9 [ids starting with x]",  # planning first
        "draws look odd (4 tasks: a, b, c and 1 more)",  # one text of several tasks: once
        "w1: w1 is special",
    ]
    for _ in range(2):  # run, then skipped: the warnings come from the manifest
        reports = by_stage(run_pipeline(WARN_TOY, cfg))
        assert reports["numbers"].warnings == expected
        assert reports["sums"].warnings == []
        assert CheckedSums.seen_warnings == {"numbers": expected, "sums": []}
    assert reports["numbers"].ran == 0


def test_failed_tasks_are_left_out_in_the_warnings_publish_sees(tmp_path):
    cfg = config(tmp_path / "o", "run.jobs=1", "numbers.ids=[a, bad1]")
    reports = by_stage(run_pipeline(WARN_TOY, cfg))
    assert reports["numbers"].warnings == ["a: draws look odd"]  # the failure is in the report's failures
    assert CheckedSums.seen_warnings["numbers"] == [
        "a: draws look odd",
        "bad1: left out: InputError: bad1: this input is broken on purpose",
    ]


def test_status_asks_the_stage_about_its_published_output_and_the_run_repairs_it(tmp_path):
    out = tmp_path / "o"
    cfg = config(out, "run.jobs=1")
    run_pipeline(WARN_TOY, cfg)
    assert [s.state for s in status(WARN_TOY, cfg)] == ["done", "done"]
    published = out / "published" / "total.txt"
    published.write_text("garbage\n")
    st = {s.stage: s for s in status(WARN_TOY, cfg)}
    assert st["sums"].state == "damaged" and st["sums"].reasons == ["published: total.txt damaged (will be replaced)"]
    reports = by_stage(run_pipeline(WARN_TOY, cfg))
    assert all(r.ran == 0 for r in reports.values())
    assert reports["sums"].repaired == ["replaced total.txt (damaged)"]
    assert [s.state for s in status(WARN_TOY, cfg)] == ["done", "done"]
    # the sums shard damaged: its stage remakes it, and publish_status sees it gone from the view
    (entry,) = Manifest(stage_dir(out, "sums")).entries().values()
    flip_byte(stage_dir(out, "sums") / entry.file)
    st = {s.stage: s for s in status(WARN_TOY, cfg)}
    assert st["sums"].state == "missing"
    assert st["sums"].reasons == [
        "1 task(s): its shard is missing or damaged (total)",
        "published: total.txt damaged (will be replaced)",
    ]
    assert by_stage(run_pipeline(WARN_TOY, cfg))["sums"].ran == 1
    assert [s.state for s in status(WARN_TOY, cfg)] == ["done", "done"]
    # a stage with new work is not asked (its publish will lay out new output anyway)
    published.unlink()
    st = {s.stage: s for s in status(WARN_TOY, config(out, "run.jobs=1", "sums.scale=5"))}
    assert st["sums"].state == "stale" and not any(r.startswith("published:") for r in st["sums"].reasons)


@pytest.mark.skipif(worker._MALLOC_TRIM is None, reason="the C library has no malloc_trim (not glibc)")
def test_return_freed_memory_gives_a_fragmented_heap_back_to_the_os():
    # What a worker's tasks leave: most of a heap freed, a few live blocks spread through it. gc alone keeps the
    # pages (glibc only returns the top of its heap); the call returns those between the live blocks.
    psutil = pytest.importorskip("psutil")
    process = psutil.Process()
    blocks = [bytes(1024) for _ in range(200_000)]  # ~200 MB of heap blocks
    live = blocks[::16]
    del blocks
    gc.collect()
    before = process.memory_info().rss
    assert return_freed_memory()
    after = process.memory_info().rss
    assert before - after > 50 * 2**20, (before, after)
    assert len(live) == 12_500


def test_return_freed_memory_collects_garbage_only_when_the_worker_has_grown(monkeypatch):
    # A full collection costs tens of ms in a worker that imported the grasp library: after the first task it
    # runs only once the worker has grown more than GC_MARGIN since its last collection.
    margin = worker.GC_MARGIN
    collections = []
    # resident size read after each trim, and again after each collection
    sizes = iter([500, 400, 420, 400 + margin + 1, 400 + margin, 400 + margin + 10, 400 + 2 * margin + 1, 450])
    monkeypatch.setattr(worker, "_collect_above", None)
    monkeypatch.setattr(worker, "resident_bytes", lambda: next(sizes))
    monkeypatch.setattr(worker.gc, "collect", lambda: collections.append(1))
    return_freed_memory()  # first task: collects, 400 after it
    assert len(collections) == 1
    return_freed_memory()  # 420: within the margin, no collection
    assert len(collections) == 1
    return_freed_memory()  # grown past the margin: collects, and the worker stays at 400 + margin (live memory)
    assert len(collections) == 2
    return_freed_memory()  # 10 bytes above that: not collected again after every task
    assert len(collections) == 2
    return_freed_memory()  # a margin above the size after the last collection: collects
    assert len(collections) == 3
    assert next(sizes, None) is None


def test_return_freed_memory_collects_every_task_where_the_size_is_unknown(monkeypatch):
    collections = []
    monkeypatch.setattr(worker, "_collect_above", None)
    monkeypatch.setattr(worker, "resident_bytes", lambda: None)
    monkeypatch.setattr(worker.gc, "collect", lambda: collections.append(1))
    for _ in range(3):
        return_freed_memory()
    assert len(collections) == 3


def test_resident_bytes_reads_this_process():
    rss = worker.resident_bytes()
    if rss is None:
        pytest.skip("no /proc/self/statm here")
    psutil = pytest.importorskip("psutil")
    assert abs(rss - psutil.Process().memory_info().rss) < 64 * 2**20


def test_entries_record_cpu_seconds_apart_from_wall_seconds(tmp_path):
    # A task that sleeps spends wall time but (almost) no CPU: the manifest keeps both, so cost models can use CPU.
    cfg = config(tmp_path / "out", "run.jobs=1", "numbers.sleep=0.2", "numbers.ids=[a]")
    run_pipeline(TOY, cfg, ["numbers"])
    (entry,) = Manifest(stage_dir(tmp_path / "out", "numbers")).entries().values()
    assert entry.seconds >= 0.2
    assert 0.0 < entry.cpu_seconds < 0.1


def test_toy_count_and_work_ms_give_the_engine_benchmark_its_tasks(tmp_path):
    # bench/bench_engine.py runs this toy at 10k tasks: generated ids, CPU burnt per task, its CPU in the meta.
    out = tmp_path / "o"
    run_pipeline(TOY, config(out, "run.jobs=1", "numbers.count=3", "numbers.work_ms=2"))
    entries = list(Manifest(stage_dir(out, "numbers")).entries().values())
    assert sorted(e.task for e in entries) == ["n000000", "n000001", "n000002"]
    for e in entries:
        assert e.meta["cpu"] >= 0.002 and e.meta["worker_cpu"] >= e.meta["cpu"] and e.meta["pid"] > 0, e.meta
    plain = tmp_path / "plain"
    run_pipeline(TOY, config(plain, "run.jobs=1"))
    assert all(e.meta == {"n": 5} for e in Manifest(stage_dir(plain, "numbers")).entries().values())


class _Checked:
    """Mix-in: a toy stage whose :meth:`check` records its name, and fails while ``failing`` names it."""

    calls: list[str] = []
    failing: set[str] = set()

    def check(self, params):
        _Checked.calls.append(self.name)
        if self.name in _Checked.failing:
            raise StageError(f"{self.name}: cannot run here")


class _CheckedNumbers(_Checked, type(TOY.stage("numbers"))):
    pass


class _CheckedSums(_Checked, type(TOY.stage("sums"))):
    pass


CHECKED_TOY = dataclasses.replace(TOY, stages=(_CheckedSums(), _CheckedNumbers()))


def test_stages_are_checked_before_the_first_task_and_only_when_they_may_run(tmp_path, monkeypatch):
    monkeypatch.setattr(_Checked, "calls", [])
    monkeypatch.setattr(_Checked, "failing", {"sums"})
    out = tmp_path / "o"
    # sums (a later wave) cannot run: the run stops before numbers, the first wave, runs any task
    with pytest.raises(StageError, match="sums: cannot run here"):
        run_pipeline(CHECKED_TOY, config(out, "run.jobs=1"))
    assert _Checked.calls == ["numbers", "sums"]
    assert Manifest(stage_dir(out, "numbers")).entries() == {}
    _Checked.failing = set()
    _Checked.calls.clear()
    run_pipeline(CHECKED_TOY, config(out, "run.jobs=1"))
    assert _Checked.calls == ["numbers", "sums"]  # each once, however many waves
    # nothing to do: no stage runs, none is checked (not even a failing one)
    _Checked.failing = {"numbers", "sums"}
    _Checked.calls.clear()
    again = by_stage(run_pipeline(CHECKED_TOY, config(out, "run.jobs=1")))
    assert _Checked.calls == [] and again["numbers"].skipped == 4 and again["sums"].skipped == 1
    # only sums has work (its params changed): numbers, planned complete, is not checked
    _Checked.calls.clear()
    with pytest.raises(StageError, match="sums: cannot run here"):
        run_pipeline(CHECKED_TOY, config(out, "run.jobs=1", "sums.scale=3"))
    assert _Checked.calls == ["sums"]


def test_a_shared_view_is_unpickled_once_per_worker_and_gives_each_task_its_subset(tmp_path, monkeypatch):
    import pickle

    from pipeline.stage import Upstream
    from pipeline.store import Entry

    entries = {
        "objects": {f"o{i}": Entry(key=f"k{i}", task=f"o{i}", status="ok", file=f"k{i}.h5", meta={"i": i})
                    for i in range(50)},
        "scenes": {"s0": Entry(key="ks", task="s0", status="ok", file="ks.h5")},
    }
    view = worker.SharedView(tmp_path, entries)
    loads = []
    real = pickle.loads
    monkeypatch.setattr(worker.pickle, "loads", lambda data: loads.append(1) or real(data))
    monkeypatch.setattr(worker, "_views", type(worker._views)())
    plain = Upstream(tmp_path, entries)
    for needs in ({"scenes": ["s0"], "objects": ["o3", "o7"]}, None, {"objects": sorted(entries["objects"])}):
        shipped = pickle.loads(pickle.dumps(view.task_view(needs)))  # as a worker receives it
        got, want = shipped.upstream(), plain.subset(needs)
        assert got.stages() == want.stages()
        for stage in want.stages():
            assert [got.entry(stage, t) for t in got.ids(stage)] == [want.entry(stage, t) for t in want.ids(stage)]
            assert [got.path(stage, t) for t in got.ids(stage)] == [want.path(stage, t) for t in want.ids(stage)]
    assert len(loads) == 3 + 1  # the three task views, and the shared entries once
    # a worker keeps a bounded number of views
    for _ in range(worker.VIEWS_KEPT + 3):
        worker.SharedView(tmp_path, entries).task_view(None).upstream()
    assert len(worker._views) == worker.VIEWS_KEPT


def test_a_task_whose_view_cannot_be_built_fails_alone(tmp_path):
    from pipeline.plan import PlannedTask
    from pipeline.stage import RunContext

    view = worker.SharedView(tmp_path, {"numbers": {}})
    stage = TOY.stage("sums")
    planned = PlannedTask(Task(id="total"), key="ab" * 32, parts={}, seed="cd" * 32)
    entry = worker.execute_task(stage, planned, None, view.task_view({"numbers": ["gone"]}), tmp_path,
                                RunContext(tmp_path, tmp_path))
    assert entry.status == "failed" and "gone" in entry.error


def test_shards_checked_side_by_side_are_judged_by_their_bytes_even_with_their_mtime_kept(tmp_path):
    import os

    from pipeline.plan import check_shards, one_check_per_shard, shard_ok

    out = tmp_path / "o"
    cfg = config(out, "run.jobs=1", "numbers.ids=[a, b, c, d, e, f, g, h]")
    run_pipeline(TOY, cfg)
    manifest = Manifest(stage_dir(out, "numbers"))
    entries = manifest.entries()
    damaged = {e.key for e in entries.values() if e.task in ("b", "g")}
    for key in damaged:
        path = manifest.stage_dir / entries[key].file
        st = path.stat()
        flip_byte(path)
        os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns))  # same size, same mtime: only the bytes tell
    with one_check_per_shard():
        check_shards(manifest, entries.values())
        side_by_side = {k: shard_ok(manifest, e) for k, e in entries.items()}
    one_by_one = {k: manifest.shard_ok(e) for k, e in entries.items()}
    assert side_by_side == one_by_one == {k: k not in damaged for k in entries}
    st = {s.stage: s for s in status(TOY, cfg)}
    assert (st["numbers"].done, st["numbers"].missing) == (6, 2)
    assert by_stage(run_pipeline(TOY, cfg))["numbers"].ran == 2


def test_own_workers_get_the_shared_view_and_a_cluster_a_plain_upstream(tmp_path):
    import joblib

    from pipeline import scheduler
    from pipeline.stage import Upstream

    out = tmp_path / "o"
    run_pipeline(TOY, config(out, "run.jobs=1"))
    sums = TOY.stage("sums")
    r = scheduler._start_stage(sums, sums.params(config(out)), out, False, {"numbers": set(
        Manifest(stage_dir(out, "numbers")).entries())})
    (planned,) = r.planned
    with joblib.parallel_config(backend="loky"):
        assert isinstance(r.shipped(planned, scheduler._own_workers()), worker.TaskView)
    with joblib.parallel_config(backend="threading"):  # stands for dask and ray: not processes of this run
        plain = r.shipped(planned, scheduler._own_workers())
    assert type(plain) is Upstream
    via_view = r.shipped(planned, True).upstream()
    assert [plain.path("numbers", t) for t in plain.ids("numbers")] == [
        via_view.path("numbers", t) for t in via_view.ids("numbers")] and len(plain.ids("numbers")) == 4


def test_a_manifest_is_parsed_once_while_it_stays_the_same_file(tmp_path, monkeypatch):
    from pipeline.plan import one_check_per_shard, read_entries
    from pipeline.store import Entry

    out = tmp_path / "o"
    run_pipeline(TOY, config(out, "run.jobs=1"))
    manifest = Manifest(stage_dir(out, "numbers"))
    parses = []
    real = Manifest.entries
    monkeypatch.setattr(Manifest, "entries", lambda self, **kw: parses.append(1) or real(self, **kw))
    with one_check_per_shard():
        first = read_entries(manifest)
        again = read_entries(manifest)
        assert again == first and again is not first and len(parses) == 1
        manifest.append(Entry(key="f" * 64, task="late", status="failed", error="x"))  # a commit: the file grows
        grown = read_entries(manifest)
        assert len(parses) == 2 and set(grown) == set(first) | {"f" * 64}
    assert read_entries(manifest) == grown and len(parses) == 3  # outside a run: read every time
