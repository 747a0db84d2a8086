"""Checking a published dataset folder: fast against its publish record (:func:`check_published`), in full against
its card (:func:`check_folder`, ``gen validate``).

The publish record describes the files one publish laid out on one disk (per file, relative to the dataset folder:
``bytes``, ``mtime_ns``, ``ino``, ``dev``, ``sha256``, and for a shard's link its ``source`` ``[stage, task id]``
and whether it is ``linked``, a hard link, or a copy). :func:`check_published` compares the folder with it from
stats alone: a link is intact when it is its verified shard's inode with its size, any other file when its size,
mtime and inode are unchanged, else its sha256 decides. What it finds (:class:`PublishCheck`) tells the dataset
stage what to repair: links to make again, stray files (:func:`graspgen.io.card.stray_files`) to remove, or the
whole folder to lay out again.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from graspgen.io.atomic import atomic_path
from graspgen.io.card import CARD_VERSION, stray_files
from graspgen.io.card_render import render_card
from graspgen.io.dataset_table import check_table
from graspgen.io.files import sha256_file

__all__ = [
    "FIRST",
    "OTHER",
    "STRAY",
    "PublishCheck",
    "ShardFile",
    "ShardLookup",
    "check_folder",
    "check_published",
    "file_record",
    "link_file",
    "read_record",
    "same_file",
]

STRAY = "not part of the dataset"
FIRST = "first"
OTHER = "other"
PROBLEMS_LISTED = 8
"""At most this many files are named in the lines of a :class:`PublishCheck`; the rest are counted."""


@dataclasses.dataclass(frozen=True)
class ShardFile:
    """A verified shard a published file may be linked to."""

    path: Path
    """The shard's file."""
    sha256: str
    """Its recorded sha256 (hex)."""
    bytes: int
    """Its recorded size."""


ShardLookup = Callable[[str, str], "ShardFile | None"]
"""``(stage, task id) -> ShardFile``, or None when the run has no verified shard of that task."""


def link_file(src: Path, dst: Path) -> None:
    """Make ``dst`` the same file as ``src``: a hard link (atomically replaced), else a copy."""
    try:
        if dst.exists() and os.path.samefile(src, dst):
            return
    except OSError:
        pass
    with atomic_path(dst) as tmp:
        tmp.unlink()
        try:
            os.link(src, tmp)
        except OSError:  # another file system, or links not allowed: copy
            shutil.copyfile(src, tmp)


def same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def read_record(path: Path) -> dict[str, Any] | None:
    """A publish record, or None when there is none or it cannot be used."""
    try:
        record = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return None
    return record if isinstance(record, dict) and isinstance(record.get("files"), dict) else None


def file_record(root: Path, rel: str, known: Mapping[str, Any]) -> dict[str, Any]:
    """``known`` (sha256, source, linked) with the file's size, mtime and inode as they are now."""
    st = os.stat(root / rel)
    return {**known, "bytes": st.st_size, "mtime_ns": st.st_mtime_ns, "ino": st.st_ino, "dev": st.st_dev}


def _unchanged(st: os.stat_result, info: Mapping[str, Any]) -> bool:
    """The file's size, mtime and inode are those the record holds (the fast check: no read)."""
    return (st.st_size, st.st_mtime_ns, st.st_ino, st.st_dev) == tuple(
        info.get(k) for k in ("bytes", "mtime_ns", "ino", "dev")
    )


def _at_most(lines: list[str], more: str) -> list[str]:
    if len(lines) <= PROBLEMS_LISTED:
        return lines
    return lines[: PROBLEMS_LISTED - 1] + [f"{len(lines) - PROBLEMS_LISTED + 1} {more}"]


@dataclasses.dataclass
class PublishCheck:
    """What :func:`check_published` found in a published folder, and what publish does about it."""

    record: dict[str, Any] = dataclasses.field(default_factory=dict)
    """The publish record read (updated by publish when it repairs)."""
    remake: str | None = None
    """The whole folder is laid out: :data:`FIRST` (no folder yet), :data:`OTHER` (it shows another dataset
    shard) or why (no record of its files, another card version). None: it is repaired file by file."""
    problems: list[tuple[str, str]] = dataclasses.field(default_factory=list)
    """``(path, what)``: missing, damaged or not part of the dataset."""
    relink: list[str] = dataclasses.field(default_factory=list)
    """Shards' links to make again."""
    stray: list[str] = dataclasses.field(default_factory=list)
    """Files in the dataset's folders that the dataset does not list: removed."""
    refresh: list[str] = dataclasses.field(default_factory=list)
    """Files with another mtime or inode but their recorded sha256 (rewritten with the same bytes, e.g. by
    ``gen report``): only their record is updated."""
    rebuild: bool = False
    """A file that is not a shard's link is damaged or missing: the whole folder is laid out again."""

    def status_lines(self) -> list[str]:
        """For ``gen status``: what a run will do."""
        if self.remake == FIRST:
            return ["not published yet (will be)"]
        if self.remake == OTHER:
            return ["the folder holds another dataset (will be made again)"]
        if self.remake is not None:
            return [f"the folder will be made again ({self.remake})"]
        lines = [f"{rel} {what} (will be {'removed' if what == STRAY else 'replaced'})" for rel, what in self.problems]
        return _at_most(lines, "file(s) more to repair")

    def done_lines(self) -> list[str]:
        """For the run's report: what publish did (a first or new dataset's publish is no repair: nothing)."""
        if self.remake in (FIRST, OTHER):
            return []
        if self.remake is not None:
            return [f"made the folder again ({self.remake})"]
        lines = [f"{'removed' if what == STRAY else 'replaced'} {rel} ({what})" for rel, what in self.problems]
        return _at_most(lines, "file(s) more repaired")


def _card_key(root: Path) -> str | None:
    try:
        return json.loads((root / "card.json").read_text()).get("dataset_key")
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, AttributeError):
        return None


def _remake(root: Path, record: dict[str, Any] | None, key: str | None) -> str | None:
    """Why the whole folder must be laid out again (None: it can be checked file by file)."""
    if record is None:
        if not (root / "card.json").exists():
            return FIRST
        if key is not None and _card_key(root) != key:
            return OTHER
        return "the folder has no record of its files"
    if key is not None and record.get("dataset_key") != key:
        return OTHER
    if not root.is_dir():
        return "the folder is missing"
    if record.get("card_version") != CARD_VERSION:
        return "the card's version changed"
    return None


def check_published(root: Path, record: dict[str, Any] | None, shard: ShardLookup, key: str | None) -> PublishCheck:
    """Compare a published dataset folder with its publish record, fast: stats, no reads (module docstring).

    A shard's link is intact when it is the shard's file (same inode) with the shard's size; the shards ``shard``
    finds are the ones the run verified, so this costs nothing. A link whose shard it does not find (a damaged
    shard the run remakes) is damaged. Any other file is intact when its size, mtime and inode are the recorded
    ones; when they are not, its sha256 decides (so a file rewritten with the same bytes is not replaced). ``key``
    is the dataset shard's key (None when it is not known: it is being remade).
    """
    check = PublishCheck(record=record or {}, remake=_remake(root, record, key))
    if check.remake is not None:
        return check
    assert record is not None
    files: dict[str, Any] = record["files"]
    for rel, info in files.items():
        try:
            st = os.stat(root / rel)
        except OSError:
            st = None
        if info.get("source") is not None:
            _check_link(check, root, rel, info, st, shard(*info["source"]))
        elif st is None:
            check.problems.append((rel, "missing"))
            check.rebuild = True
        elif not _unchanged(st, info):
            if sha256_file(root / rel) == info.get("sha256"):
                check.refresh.append(rel)
            else:
                check.problems.append((rel, "damaged"))
                check.rebuild = True
    for rel in stray_files(root, files):
        check.problems.append((rel, STRAY))
        check.stray.append(rel)
    return check


def _check_link(check: PublishCheck, root: Path, rel: str, info: Mapping[str, Any], st: os.stat_result | None,
                entry: ShardFile | None) -> None:
    """The fast check of one shard's published link (or copy), recorded in ``check``."""
    if st is None or entry is None:
        check.problems.append((rel, "missing" if st is None else "damaged"))
        check.relink.append(rel)
        if entry is not None and entry.sha256 != info.get("sha256"):
            check.rebuild = True  # the shard was remade with other bytes: the card changes too
        return
    shard_st = os.stat(entry.path)
    if (st.st_ino, st.st_dev) == (shard_st.st_ino, shard_st.st_dev) and st.st_size == entry.bytes:
        return
    if not info.get("linked") and _unchanged(st, info):
        return  # a copy (no hard links there), untouched since it was made
    if st.st_size != entry.bytes or sha256_file(root / rel) != entry.sha256:
        check.problems.append((rel, "damaged"))
        check.relink.append(rel)
    elif info.get("linked"):
        check.relink.append(rel)  # an intact separate copy of a linked file: linked again, silently
    else:
        check.refresh.append(rel)
    if entry.sha256 != info.get("sha256"):
        check.rebuild = True


def check_folder(root: Path) -> tuple[list[str], int]:
    """Check a published dataset folder against its card, reading every byte (``gen validate``'s folder part).

    Every file listed in ``card.json`` exists with its size and sha256 and no other file sits in the dataset's
    folders; grasps.parquet passes :func:`graspgen.io.dataset_table.check_table`; card.md is the rendering of
    card.json.

    Returns
    -------
    (problems, files_checked)
        Each problem starts with the path of the file at fault.
    """
    problems: list[str] = []
    checked = 0
    try:
        card = json.loads((root / "card.json").read_text())
    except (OSError, json.JSONDecodeError) as exc:
        return [f"{root / 'card.json'}: cannot read the card ({exc})"], checked
    listed = card.get("files", {})
    for rel, info in listed.items():
        f = root / rel
        checked += 1
        if not f.is_file():
            problems.append(f"{f}: missing (listed in card.json)")
        elif f.stat().st_size != info["bytes"] or sha256_file(f) != info["sha256"]:
            problems.append(f"{f}: sha256 differs from card.json's (the file was changed)")
    problems += [f"{root / rel}: not part of the dataset (not listed in card.json)"
                 for rel in stray_files(root, listed)]
    problems += check_table(root, card)
    try:
        if (root / "card.md").read_text() != render_card(card):
            problems.append(f"{root / 'card.md'}: is not the rendering of card.json (run gen report)")
    except OSError:
        problems.append(f"{root / 'card.md'}: missing")
    return problems, checked
