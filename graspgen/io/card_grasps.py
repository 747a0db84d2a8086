"""The dataset card's "Scene grasps" section: per object, how the grasps stage got its candidates.

:func:`scene_grasp_counts` sums the per-object counts the grasps stage writes into each scene shard's metadata
(:func:`graspgen.workflows.scene_grasps.sample_scene_grasps`, ``meta["objects"]``) over the scenes; it is what
``card.json`` holds under ``scene_grasps``. :func:`scene_grasps_lines` renders it as Markdown (a pure function of
that dict). Shards written before the counts existed have no ``objects`` entry: the section then says so.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

__all__ = ["PREFILTER_KEYS", "scene_grasp_counts", "scene_grasps_lines"]

PREFILTER_KEYS = ("collision_with_ground", "collision_with_target", "collision_with_clutter")
"""The pre-filter's rejection causes, in code order."""


def _empty() -> dict[str, Any]:
    return {"scenes": 0, "tried": 0, "unreachable": {"ground": 0, "target": 0},
            "rejected": {k: 0 for k in PREFILTER_KEYS}, "kept": {"free": 0, "collisions": 0}, "short": 0}


def scene_grasp_counts(metas: Iterable[Mapping[str, Any]]) -> dict[str, Any]:
    """Per-object sums of the grasps stage's counts over scene shards' metadata.

    Parameters
    ----------
    metas : iterable of mapping
        Each scene's grasps-shard metadata (its ``objects`` list).

    Returns
    -------
    dict
        ``{"objects": {name: {"scenes", "tried", "unreachable": {ground, target}, "rejected": {cause: n},
        "kept": {free, collisions}, "short" (scenes that stopped short of the target), "tried_per_kept"}},
        "total": the same summed over objects, except "scenes" (distinct scenes with counts) and "object_scenes"
        (the sum: object-scene pairs)}``; ``{"objects": {}, "total": None}`` when no shard has counts.
    """
    objects: dict[str, dict[str, Any]] = {}
    scenes = 0
    for meta in metas:
        scenes += bool(meta.get("objects"))
        for o in meta.get("objects") or ():
            acc = objects.setdefault(str(o["object_name"]), _empty())
            acc["scenes"] += 1
            acc["tried"] += int(o["tried"])
            for k in acc["unreachable"]:
                acc["unreachable"][k] += int(o["unreachable"][k])
            for k in PREFILTER_KEYS:
                acc["rejected"][k] += int(o["prefilter"][k])
            for k in acc["kept"]:
                acc["kept"][k] += int(o["kept"][k])
            acc["short"] += int(o["stopped"] != "target")
    if not objects:
        return {"objects": {}, "total": None}
    total = _empty()
    for acc in objects.values():
        for key, value in acc.items():
            if isinstance(value, dict):
                for k, v in value.items():
                    total[key][k] += v
            else:
                total[key] += value
    total["object_scenes"] = total["scenes"]
    total["scenes"] = scenes  # distinct scenes, not the sum over objects (an object-scene pair each)
    for acc in (*objects.values(), total):
        kept = acc["kept"]["free"] + acc["kept"]["collisions"]
        acc["tried_per_kept"] = round(acc["tried"] / kept, 3) if kept else None
    return {"objects": {k: objects[k] for k in sorted(objects)}, "total": total}


def scene_grasps_lines(section: Mapping[str, Any] | None) -> list[str]:
    """The card's "Scene grasps" Markdown lines for :func:`scene_grasp_counts`' dict (none when it is None)."""
    if section is None:
        return []
    lines = ["## Scene grasps", ""]
    if not section.get("objects"):
        return lines + ["The grasps shards carry no per-object counts (made before they existed).", ""]
    lines += [
        "Per object, over its scenes: candidates tried, screened out before the pre-filter as unreachable "
        "(the hand below the table, or through the target), rejected by the pre-filter (ground, target, clutter; "
        "kept or not) and kept (free: simulated by the rollouts; collisions: labelled, up to "
        "grasps.collision_share of the rows). Short: scenes that stopped before max_per_object free candidates. "
        "In the all row, scenes counts distinct scenes; every other column sums the objects' rows (short counts "
        "object-scene pairs).",
        "",
        "| object | scenes | tried | unreachable ground | unreachable target | rejected ground | rejected target "
        "| rejected clutter | kept free | kept collisions | short | tried per kept |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    rows = [*section["objects"].items(), ("all", section["total"])]
    for name, o in rows:
        per = "-" if o["tried_per_kept"] is None else f"{o['tried_per_kept']:.1f}"
        cells = [o["scenes"], o["tried"], o["unreachable"]["ground"], o["unreachable"]["target"],
                 *(o["rejected"][k] for k in PREFILTER_KEYS), o["kept"]["free"], o["kept"]["collisions"], o["short"]]
        lines.append(f"| {name} | " + " | ".join(str(c) for c in cells) + f" | {per} |")
    return lines + [""]
