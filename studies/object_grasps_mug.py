"""The calibration mug (ACRONYM's example) through :func:`graspgen.workflows.object_grasps.label_object_grasps`.

The mug of the calibration folder's ``acronym_mug/`` (its README: ShapeNetSem mesh under ``meshes/``, scaled by the
ACRONYM file's ``object/scale``; mass and friction from the file) is prepared like ``gen evaluate`` prepares it
(:func:`graspgen.workflows.prepare.prepare_object`, the cheap CoACD of
:data:`graspgen.workflows.evaluate_settings.CHEAP_COACD`, cached in ``.cache/coacd``) and labelled with the Panda and
the ``acronym`` protocol up to 1,000 positives and 1,000 negatives (``--positives``, ``--negatives``; at most
``--max-candidates`` 20,000 rollouts).

Printed: our success rate among all tried antipodal candidates beside FleX's on ACRONYM's grasps of the same mug
(the file's ``object_in_gripper``, 0.64), and, because ACRONYM's grasps were sampled differently, the parts of ours
that compare: the antipodal candidates whose open hand did not intersect the mug at placement (outcomes 3-5: what a
collision check before simulation keeps), and the near misses. Not a test of agreement (the two sets hold different
grasps; ``studies/fidelity.py`` labels ACRONYM's own grasps).

Saved: ``studies/object_grasps_mug.png``, three orthographic views (mesh frame x-y, x-z, y-z) of points on the mug's
surface (grey) with the kept grasps' centres (the TCP, midway between the pads) green for successes and red for
failures.

Usage: ``python -m studies.object_grasps_mug [--positives 1000] [--negatives 1000] [--max-candidates 20000]
[--calibration DIR] [--png studies/object_grasps_mug.png]``
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from graspgen.geometry.stable_poses import StablePoseParams
from graspgen.io.acronym import read_acronym
from graspgen.io.arrow import column_array
from graspgen.io.objects import ObjectRecord
from graspgen.sim.protocols import OUTCOME_NAMES
from graspgen.workflows.evaluate_settings import CHEAP_COACD
from graspgen.workflows.object_grasps import label_object_grasps
from graspgen.workflows.object_grasps_settings import ObjectGraspsParams
from graspgen.workflows.prepare import prepare_object
from studies.calibration import REPO, STUDIES, add_calibration_option

COLLISIONS = ("collision_with_ground", "collision_with_target", "collision_with_clutter")


def mug_record(folder: Path) -> tuple[ObjectRecord, float]:
    """The calibration mug as an object record (friction in its attrs) and FleX's success rate on its grasps."""
    (h5,) = sorted(folder.glob("*.h5"))
    acr = read_acronym(h5)
    prep = prepare_object(folder / acr.object_file, mass=acr.object_mass, scale=acr.object_scale, max_extent=1.0,
                          coacd=CHEAP_COACD, poses=StablePoseParams(settle_check=False, max_poses=1),
                          rng=np.random.default_rng(0), coacd_cache_dir=REPO / ".cache" / "coacd")
    friction = 1.0 if acr.object_friction is None else float(acr.object_friction)
    record = ObjectRecord(
        name="mug", vertices=np.asarray(prep.vertices), faces=np.asarray(prep.faces),
        convex_parts=[(np.asarray(v), np.asarray(f)) for v, f in prep.convex_parts], mass=float(prep.mass.mass),
        center_of_mass=np.asarray(prep.mass.center_of_mass), inertia=np.asarray(prep.mass.inertia),
        stable_poses=np.asarray(prep.stable_transforms), stable_probabilities=np.asarray(prep.stable_probabilities),
        attrs={"friction": friction},
    )
    return record, float(np.mean(acr.success))


def rate(counts: dict[str, int], names=None) -> tuple[float, int]:
    """(success share, n) among the outcomes ``names`` (all when None) of a histogram."""
    n = sum(v for k, v in counts.items() if names is None or k in names)
    return (counts["success"] / n if n else float("nan")), n


def picture(record: ObjectRecord, table, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import trimesh

    mesh = trimesh.Trimesh(record.vertices, record.faces, process=False)
    points, _ = trimesh.sample.sample_surface(mesh, 6000, seed=0)
    centres = column_array(table, "pose_object", (4, 4))[:, :3, 3]
    ok = table.column("success").to_numpy(zero_copy_only=False)
    fig, axes = plt.subplots(1, 3, figsize=(15, 5.4))
    for ax, (i, j), title in zip(axes, ((0, 1), (0, 2), (1, 2)), ("top (x-y)", "front (x-z)", "side (y-z)")):
        ax.scatter(points[:, i], points[:, j], s=1, c="0.7", lw=0)
        ax.scatter(centres[~ok, i], centres[~ok, j], s=5, c="tab:red", lw=0, alpha=0.6,
                   label=f"failure ({int((~ok).sum())})")
        ax.scatter(centres[ok, i], centres[ok, j], s=5, c="tab:green", lw=0, alpha=0.8,
                   label=f"success ({int(ok.sum())})")
        ax.set_aspect("equal")
        ax.set_title(title)
        ax.set_xlabel("xyz"[i] + " (m)")
        ax.set_ylabel("xyz"[j] + " (m)")
    axes[0].legend(loc="upper left", fontsize=8, markerscale=3)
    fig.suptitle("Calibration mug: grasp centres (TCP) of the object-centric set, Panda, acronym protocol")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--positives", type=int, default=1000)
    ap.add_argument("--negatives", type=int, default=1000)
    ap.add_argument("--max-candidates", type=int, default=20000)
    add_calibration_option(ap, "acronym_mug")
    ap.add_argument("--png", type=Path, default=STUDIES / "object_grasps_mug.png")
    args = ap.parse_args(argv)
    record, flex = mug_record(args.calibration)
    params = ObjectGraspsParams(gripper="panda", protocol="acronym", selection="balanced", label="held",
                                target_positives=args.positives,
                                target_negatives=args.negatives, max_candidates=args.max_candidates)
    t0 = time.perf_counter()
    table, meta = label_object_grasps(record, params, np.random.default_rng(0))
    seconds = time.perf_counter() - t0
    by = meta["outcomes_by_candidate"]
    anti, n_anti = rate(by["antipodal"])
    anti_free, n_free = rate(by["antipodal"], ("no_contact_established", "slipped_during_lifting", "success"))
    near, n_near = rate(by["near_miss"])
    print(f"calibration mug: {meta['tried']} candidates tried in {seconds:.1f} s ({meta['rollouts_per_s']} "
          f"rollouts/s); kept {meta['positives']} of {args.positives} positives and {meta['negatives']} of "
          f"{args.negatives} negatives (reached: {meta['reached']})")
    print(f"  success among all tried antipodal candidates: {anti:.3f} (n = {n_anti})   FleX on ACRONYM's grasps of "
          f"this mug: {flex:.2f}")
    print(f"  ... among the antipodal candidates not in collision at placement: {anti_free:.3f} (n = {n_free}); "
          f"near misses: {near:.3f} (n = {n_near})")
    for kind in ("antipodal", "near_miss"):
        total = max(sum(by[kind].values()), 1)
        shares = ", ".join(f"{name} {100 * by[kind][name] / total:.1f}%" for name in OUTCOME_NAMES if by[kind][name])
        print(f"  {kind} outcomes: {shares}")
    eps = table.column("epsilon").to_numpy()
    ok = table.column("success").to_numpy(zero_copy_only=False)
    if ok.any():
        print(f"  epsilon of the kept successes: median {np.nanmedian(eps[ok]):.4f}, "
              f"{100 * np.mean(eps[ok] > 0):.1f}% in force closure")
    picture(record, table, args.png)
    print(f"wrote {args.png}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
