"""Byte-reproducibility check: same config -> same shard hashes, whatever the workers or interruptions.

Runs a pipeline's CLI three ways into separate folders and compares every stage manifest's
``task -> sha256`` map:

1. ``--jobs 1`` with a cold cache (the reference);
2. ``--jobs 2`` with a warm cache;
3. ``--jobs 2``, killed with SIGKILL (whole process group, workers included) as soon as the first shard is
   committed, started again and killed again half-way and near the end (so later stages are interrupted too),
   then run to the end.

Usage::

    python -m pipeline.repro --config configs/smoke.yaml --workdir build/repro -- .venv/bin/gen

Exit status 0 when all three agree, 1 otherwise (the differing shards are listed).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

from pipeline.store import MANIFEST, SHARDS


def shard_hashes(out: Path) -> dict[str, str]:
    """``{"stage/task": sha256}`` of the successful entries in every manifest under ``out`` (latest per task)."""
    hashes: dict[str, str] = {}
    for manifest in sorted(out.glob(f"{SHARDS}/*/{MANIFEST}")):
        stage = manifest.parent.name
        for line in manifest.read_text().splitlines():
            try:
                entry = json.loads(line)
            except json.JSONDecodeError:
                continue
            if entry.get("status") == "ok":
                hashes[f"{stage}/{entry['task']}"] = entry["sha256"]
    return hashes


def _run(cmd: list[str], config: str, out: Path, cache: Path, jobs: int) -> None:
    args = [*cmd, "run", "--config", config, "--out", str(out), "--jobs", str(jobs), "--set", f"run.cache_dir={cache}"]
    print("$", " ".join(args), flush=True)
    proc = subprocess.run(args, text=True, capture_output=True)
    if proc.returncode != 0:
        sys.stdout.write(proc.stdout + proc.stderr)
        raise SystemExit(f"repro: run into {out} failed with exit code {proc.returncode}")


def _committed_lines(out: Path) -> int:
    return sum(len(m.read_text().splitlines()) for m in out.glob(f"{SHARDS}/*/{MANIFEST}"))


def _run_and_kill(
    cmd: list[str], config: str, out: Path, cache: Path, jobs: int, after: int, timeout: float = 600
) -> int:
    """Start a run, SIGKILL its process group once ``after`` manifest lines exist; return the count then."""
    args = [*cmd, "run", "--config", config, "--out", str(out), "--jobs", str(jobs), "--set", f"run.cache_dir={cache}"]
    print("$", " ".join(args), f" # killed with SIGKILL at {after} committed shard(s)", flush=True)
    proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        lines = _committed_lines(out)
        if lines >= after:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
            return lines
        if proc.poll() is not None:
            raise SystemExit("repro: the run finished before it could be killed; use a config with more tasks")
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGKILL)
    raise SystemExit(f"repro: no shard committed within {timeout} s")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", required=True)
    parser.add_argument("--workdir", default="build/repro", type=Path)
    parser.add_argument("cmd", nargs="+", help="the pipeline's CLI, e.g. .venv/bin/gen")
    opts = parser.parse_args(argv)
    work: Path = opts.workdir
    if work.exists():
        shutil.rmtree(work)
    work.mkdir(parents=True)
    cache = work / "cache"

    t0 = time.perf_counter()
    _run(opts.cmd, opts.config, work / "jobs1", cache, 1)
    t1 = time.perf_counter()
    _run(opts.cmd, opts.config, work / "jobs2", cache, 2)
    t2 = time.perf_counter()
    ref = shard_hashes(work / "jobs1")
    kills = []
    for after in sorted({1, len(ref) // 2, len(ref) - 1}):
        if after > _committed_lines(work / "killed"):
            kills.append(_run_and_kill(opts.cmd, opts.config, work / "killed", work / "cache-killed", 2, after))
    _run(opts.cmd, opts.config, work / "killed", work / "cache-killed", 2)
    t3 = time.perf_counter()

    runs = {"jobs2": shard_hashes(work / "jobs2"), "killed+resumed": shard_hashes(work / "killed")}
    print(f"reference (--jobs 1, cold cache): {len(ref)} shards in {t1 - t0:.1f} s")
    print(f"--jobs 2, warm cache: {t2 - t1:.1f} s")
    print(f"killed {len(kills)} times, at {kills} committed shard(s), then resumed: {t3 - t2:.1f} s")
    ok = bool(ref)
    for name, hashes in runs.items():
        diff = sorted(k for k in set(ref) | set(hashes) if ref.get(k) != hashes.get(k))
        if diff:
            ok = False
            print(f"MISMATCH {name}: {len(diff)} shard(s) differ from the reference:")
            for k in diff[:20]:
                print(f"  {k}: {ref.get(k)} != {hashes.get(k)}")
        else:
            print(f"identical {name}: all {len(hashes)} shard hashes equal the reference")
    print("repro: OK" if ok else "repro: FAILED")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
