"""The dataset card of a published dataset: ``card.json`` (the statistics and provenance as data) and ``card.md``.

A card is made in three steps, so that this module needs no picture code (the dataset stage draws the plots,
:mod:`graspgen.viz.plots`, between them):

1. :func:`graspgen.io.card_stats.card_stats`: the counts per object and outcome, each label's summary and histogram
   and the labels' correlations, from the files in the dataset folder;
2. the plots, drawn from those statistics and the table they were computed from;
3. :func:`write_card`: ``card.json`` and its Markdown rendering ``card.md`` (:func:`graspgen.io.card_render.
   render_card`, a pure function of card.json), and the files of an earlier dataset removed.

What the files cannot tell (the shard keys, the config, the package versions, the data files' hashes) comes in as
``provenance`` and ``files``. :func:`card_sources` reads them back from a published card, to render it again
(``gen report``). :func:`stray_files` is the one scan for files in the dataset's folders that a card does not list.
"""

from __future__ import annotations

import dataclasses
import json
import os
import platform
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from graspgen.errors import InputError
from graspgen.io.atomic import write_text_atomic
from graspgen.io.card_learn import learnability
from graspgen.io.card_render import render_card
from graspgen.io.card_stats import CardSettings
from graspgen.io.dataset_table import FORMAT, dataset_dir
from graspgen.io.files import sha256_file

__all__ = [
    "CARD_VERSION",
    "MANAGED",
    "CardSources",
    "add_file",
    "card_sources",
    "package_versions",
    "stray_files",
    "write_card",
]

CARD_VERSION = 5
"""Bump when the card's content or the plots change: published folders are then re-rendered."""

MANAGED = ("scenes", "objects", "acronym", "acronym/meshes", "plots", "graspgen", "graspgen/objects", "probe",
           "contact_graspnet", "contact_graspnet/scene_contacts", "contact_graspnet/meshes", "contact_graspnet/splits")
"""Subfolders of a dataset folder that the card owns: files there that it does not list are not part of the
dataset (:func:`stray_files`), and :func:`write_card` removes them."""

PROVENANCE = ("dataset_key", "tables", "left_out", "stages", "versions", "config")
"""The keys of ``provenance`` that :func:`write_card` needs (``warnings`` and ``scene_grasps`` are optional)."""


def stray_files(root: Path, listed: Mapping[str, Any]) -> list[str]:
    """The files in the :data:`MANAGED` folders of ``root`` that ``listed`` (relative paths) does not hold.

    Hidden files (a name starting with ``.``) are left alone; a symbolic link counts as the file it points to.
    The one scan for stray files: publish removes them, the run's check and ``gen validate`` name them.

    Returns
    -------
    list of str
        Relative paths (``plots/old.png``), by folder in :data:`MANAGED` order, then by name.
    """
    stray = []
    for sub in MANAGED:
        try:
            found = sorted(os.scandir(root / sub), key=lambda d: d.name)
        except OSError:  # no such folder
            continue
        for item in found:
            rel = f"{sub}/{item.name}"
            if rel not in listed and not item.name.startswith(".") and item.is_file():
                stray.append(rel)
    return stray


def add_file(files: dict[str, dict[str, Any]], root: Path, rel: str) -> None:
    """Add ``root/rel`` to ``files`` (a card's file list) with its sha256 and size."""
    path = root / rel
    files[rel] = {"sha256": sha256_file(path), "bytes": path.stat().st_size}


def package_versions() -> dict[str, str]:
    """Python and the versions of the packages that shape the data (and this one)."""
    from importlib import metadata

    out = {"python": platform.python_version()}
    for name in ("graspgen", "numpy", "scipy", "mujoco", "trimesh", "coacd", "manifold3d", "embreex", "h5py",
                 "pyarrow", "joblib", "pillow", "matplotlib"):
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def _schema_doc(schema: pa.Schema) -> list[dict[str, str]]:
    return [
        {
            "name": f.name,
            "type": str(f.type),
            "description": (f.metadata or {}).get(b"description", b"").decode(),
        }
        for f in schema
    ]


def write_card(
    root: Path,
    provenance: Mapping[str, Any],
    files: Mapping[str, Any],
    stats: Mapping[str, Any],
    plots: list[str],
) -> dict[str, Any]:
    """Write ``card.json`` and ``card.md`` in ``root`` and remove the stray files of its folders.

    Parameters
    ----------
    root : Path
        The dataset folder (grasps.parquet, scenes/, objects/ in place).
    provenance : mapping
        ``dataset_key``, ``tables``, ``left_out``, ``stages`` (version and keys per stage), ``versions``,
        ``config``, optionally ``warnings`` and ``scene_grasps``: what the data alone cannot tell.
    files : mapping
        ``{relative path: {"sha256", "bytes", ...}}`` of the data files and the plots.
    stats : mapping
        :func:`graspgen.io.card_stats.card_stats` of the folder.
    plots : list of str
        The plots drawn (relative paths, in ``files``), in the order the card shows them.

    Returns
    -------
    dict
        What card.json holds.
    """
    schema = pq.read_schema(root / "grasps.parquet")
    card = {
        "format": FORMAT,
        "card_version": CARD_VERSION,
        "dataset_key": provenance["dataset_key"],
        "tables": list(provenance["tables"]),
        **stats,
        "left_out": dict(provenance["left_out"]),
        "warnings": [str(w) for w in provenance.get("warnings", [])],
        "schema": _schema_doc(schema),
        "plots": plots,
        "learnability": learnability(root, files, provenance["config"], provenance.get("warnings", [])),
        "scene_grasps": provenance.get("scene_grasps"),  # per-object sampling counts (graspgen.io.card_grasps)
        "files": {k: files[k] for k in sorted(files)},
        "stages": provenance["stages"],
        "versions": provenance["versions"],
        "config": provenance["config"],
    }
    card = json.loads(json.dumps(card, allow_nan=False))  # what card.json holds is exactly what is rendered
    write_text_atomic(root / "card.json", json.dumps(card, indent=1) + "\n")
    write_text_atomic(root / "card.md", render_card(card))
    for rel in stray_files(root, card["files"]):  # those of an earlier dataset
        (root / rel).unlink()
    return card


@dataclasses.dataclass(frozen=True)
class CardSources:
    """What a published card holds that its data files cannot tell: enough to make the card again."""

    root: Path
    """The dataset folder."""
    provenance: dict[str, Any]
    """:data:`PROVENANCE` with ``warnings`` and ``scene_grasps``, as :func:`write_card` takes them."""
    data_files: dict[str, Any]
    """The files card.json lists except the plots (relative path -> sha256 and bytes)."""
    settings: CardSettings
    """The card settings of the config the dataset was made with."""


def card_sources(path: str | Path) -> CardSources:
    """Read a published card back for rendering it again, after checking that every data file it lists is there.

    Raises
    ------
    InputError
        No dataset there; card.json unreadable or incomplete; a data file it lists missing or of another size
        (truncated). The message names the file.
    """
    root = dataset_dir(path)
    card_path = root / "card.json"
    try:
        old = json.loads(card_path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{card_path}: cannot read the card ({exc}); publish again with gen run") from None
    needed = (*PROVENANCE, "files")
    missing = [k for k in needed if k not in old] if isinstance(old, dict) else list(needed)
    if missing or not isinstance(old["files"], dict) or not isinstance(old["config"], dict):
        raise InputError(f"{card_path}: not a complete dataset card (no {', '.join(missing) or 'files/config'}); "
                         "publish again with gen run")
    fields = {f.name for f in dataclasses.fields(CardSettings)}
    settings = CardSettings(**{k: v for k, v in (old["config"].get("dataset") or {}).items() if k in fields})
    data_files = {k: v for k, v in old["files"].items() if not k.startswith("plots/")}
    for rel, info in data_files.items():  # a truncated or missing data file: name it, before reading any
        f = root / rel
        size = f.stat().st_size if f.is_file() else None
        listed = info.get("bytes") if isinstance(info, dict) else None
        if size is None or size != listed:
            state = "missing" if size is None else f"{size} bytes, card.json says {listed} (truncated?)"
            raise InputError(f"{f}: {state}; gen validate {path} lists every damaged file")
    provenance = {k: old[k] for k in PROVENANCE}
    provenance["warnings"] = old.get("warnings", [])
    provenance["scene_grasps"] = old.get("scene_grasps")
    return CardSources(root=root, provenance=provenance, data_files=data_files, settings=settings)
