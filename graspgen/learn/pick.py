"""Use a trained evaluator to pick grasps: sample candidates on a mesh, score them, simulate the best and random ones.

The end-to-end check of a model (``gen probe pick``): does ranking by the network's score pick grasps that hold
more often than picking at random?

1. :func:`sample_candidates`: the mesh is loaded, repaired and brought to metres as
   :func:`graspgen.workflows.prepare.prepare_object` does it (so the candidates are in the frame
   :func:`graspgen.workflows.evaluate.evaluate_grasps` rolls them out in), and antipodal candidates are drawn over the
   whole sphere as the object-grasps stage draws them (:func:`graspgen.geometry.antipodal.sample_antipodal` with
   ``approach="any"``: every call's candidates shuffled, calls repeated until ``n`` are there).
2. :func:`pick`: the model scores every candidate (:meth:`graspgen.learn.train.TrainedModel.score`); the top ``k``
   by score (ties by candidate index) among the candidates whose open hand holds none of ``hand_check_points``
   surface points (:func:`hand_hits`: the others would strike the object at placement), and ``k`` drawn uniformly
   without replacement from all candidates, and ``k`` from the clear ones.
3. :func:`simulate_pick`: the groups rolled out with :func:`graspgen.workflows.evaluate.evaluate_grasps` (the model's
   gripper, the ``acronym`` protocol: placed open, close, shake; friction 1.0 as the object-grasps stage uses);
   the success rate of each.

Every draw comes from the generator passed in: the same mesh, model, settings and seed give the same picks.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

from graspgen.errors import InputError
from graspgen.geometry.antipodal import AntipodalParams, sample_antipodal
from graspgen.geometry.mesh_io import load_mesh
from graspgen.geometry.repair import repair_mesh
from graspgen.geometry.units import normalize_units
from graspgen.grippers import load_gripper
from graspgen.learn.features import hand_boxes, surface_points
from graspgen.learn.sources import ObjectGraspSet
from graspgen.validation import check, check_int, check_number, check_rng
from graspgen.workflows.object_grasps_settings import free_space_sampler

__all__ = ["Candidates", "Pick", "PickParams", "hand_hits", "pick", "sample_candidates", "simulate_pick"]

EMPTY_CALLS = 3
"""Consecutive sampler calls without a candidate after which the mesh is given up (too big or too thin for the
gripper), as the object-grasps stage gives an object up."""


@dataclasses.dataclass(frozen=True)
class PickParams:
    """How :func:`pick` samples and chooses."""

    candidates: int = 1000
    """Candidates sampled over the object (antipodal, whole sphere)."""
    top: int = 10
    """Grasps chosen by score, and as many at random."""
    scale: float | None = None
    """Metres per mesh unit; None detects millimetres / centimetres from the size (with a warning)."""
    sampler: AntipodalParams = dataclasses.field(default_factory=free_space_sampler)
    """The antipodal sampler (the object-grasps stage's default,
    :func:`graspgen.workflows.object_grasps_settings.free_space_sampler`)."""
    max_extent: float = 1.0
    """Largest accepted object extent after scaling, m (as
    :class:`graspgen.workflows.evaluate_settings.EvaluateParams`)."""
    friction: float = 1.0
    """Object friction of the rollouts (dimensionless; 1.0: ACRONYM's and the object-grasps stage's)."""
    density: float = 700.0
    """Object density of the rollouts, kg/m^3 (ACRONYM's files: 150)."""
    hand_check_points: int = 20000
    """Surface points tested against the open hand's boxes (:func:`graspgen.learn.features.hand_boxes`) before the
    top group is chosen: a candidate whose hand holds any of them would strike the object at placement and is not
    picked (0: no check). docs/decisions/2026-12-07-pick-ensemble.md."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "candidates", check_int("candidates", self.candidates, low=1))
        object.__setattr__(self, "top", check_int("top", self.top, low=1))
        check("top", self.top <= self.candidates, f"be <= candidates ({self.candidates})", self.top)
        if self.scale is not None:
            object.__setattr__(self, "scale", check_number("scale", self.scale, low=0.0, low_open=True))
        check("sampler", isinstance(self.sampler, AntipodalParams), "be AntipodalParams", self.sampler)
        if self.sampler.approach != "any":
            object.__setattr__(self, "sampler", dataclasses.replace(self.sampler, approach="any"))
        object.__setattr__(self, "max_extent", check_number("max_extent", self.max_extent, low=0.0, low_open=True))
        object.__setattr__(self, "friction", check_number("friction", self.friction, low=0.0, low_open=True))
        object.__setattr__(self, "density", check_number("density", self.density, low=0.0, low_open=True))
        object.__setattr__(self, "hand_check_points", check_int("hand_check_points", self.hand_check_points, low=0))


@dataclasses.dataclass(frozen=True)
class Candidates:
    """Grasp candidates on one mesh, in its scaled frame."""

    mesh_path: Path
    """The mesh file."""
    scale: float
    """Metres per mesh unit used."""
    vertices: np.ndarray
    """``(v, 3) float64`` the repaired, scaled mesh (m)."""
    faces: np.ndarray
    """``(f, 3) int64``."""
    T_tcp: np.ndarray
    """``(n, 4, 4) float64`` TCP poses in the mesh frame (m)."""
    width: np.ndarray
    """``(n,) float64`` pad separation at the sampled contacts (m)."""
    warnings: tuple[str, ...] = ()
    """Unit guesses of the mesh preparation."""


def sample_candidates(mesh_path: str | Path, gripper: str, n: int, rng: np.random.Generator,
                      params: PickParams | None = None) -> Candidates:
    """``n`` antipodal candidates over the whole sphere on a mesh file (module docstring, step 1).

    Raises
    ------
    InputError
        The mesh cannot be used (names the file), or the sampler finds no candidate on it for ``gripper``.
    """
    params = PickParams(candidates=n, top=1) if params is None else params
    n = check_int("n", n, low=1)
    check_rng("rng", rng)
    spec = load_gripper(gripper)
    path = Path(mesh_path)
    mesh, _ = repair_mesh(load_mesh(path))
    mesh, scale, warning = normalize_units(mesh, scale=params.scale, max_extent=params.max_extent)
    poses, widths, empty = [], [], 0
    have = 0
    while have < n and empty < EMPTY_CALLS:
        cands = sample_antipodal(mesh, spec, params.sampler, rng)
        if len(cands) == 0:
            empty += 1
            continue
        empty = 0
        order = rng.permutation(len(cands))  # a call's candidates come in runs per contact pair: mix them
        poses.append(cands.pose_object[order])
        widths.append(cands.width[order])
        have += len(cands)
    if have == 0:
        raise InputError(f"{path}: the antipodal sampler finds no grasp on it that the {spec.name} opens around "
                         f"(max width {spec.max_width} m; check the mesh's scale)")
    return Candidates(mesh_path=path, scale=float(scale), vertices=np.asarray(mesh.vertices, dtype=np.float64),
                      faces=np.asarray(mesh.faces, dtype=np.int64), T_tcp=np.concatenate(poses)[:n],
                      width=np.concatenate(widths)[:n], warnings=(warning,) if warning else ())


@dataclasses.dataclass(frozen=True)
class Pick:
    """The candidates, their scores and the two groups :func:`pick` chose."""

    candidates: Candidates
    scores: np.ndarray
    """``(n,) float64`` the model's success probability per candidate."""
    top: np.ndarray
    """``(k,) int64`` indices of the ``k`` best-scored candidates, best first (with the hand check: the clear ones
    first, the others only when fewer than ``k`` are clear)."""
    random: np.ndarray
    """``(k,) int64`` indices of ``k`` candidates drawn uniformly without replacement."""
    clear: np.ndarray | None = None
    """``(n,) bool`` candidates whose open hand holds no surface point (None: not checked)."""
    random_clear: np.ndarray | None = None
    """``(k,) int64`` indices of ``k`` candidates drawn uniformly from the clear ones (None: not checked)."""


def pick(model: Any, mesh_path: str | Path, params: PickParams, rng: np.random.Generator) -> Pick:
    """Sample ``params.candidates`` candidates on the mesh for the model's gripper, score them with ``model`` (a
    :class:`graspgen.learn.train.TrainedModel`) and choose the top ``params.top`` and as many at random.

    Fewer candidates than asked (a small object) are all used; ``k`` is then at most their number.
    """
    cands = sample_candidates(mesh_path, model.gripper, params.candidates, rng, params)
    n = len(cands.width)
    candidate_set = ObjectGraspSet(name=Path(mesh_path).stem, group=Path(mesh_path).stem, vertices=cands.vertices,
                                   faces=cands.faces, T_tcp=cands.T_tcp, width=cands.width,
                                   label=np.zeros(n, dtype=bool), gripper=model.gripper, source="candidates")
    scores = np.asarray(model.score([candidate_set], seed=int(rng.integers(0, 2**31 - 1)))[0], dtype=np.float64)
    k = min(params.top, n)
    random = np.sort(rng.choice(n, size=k, replace=False)).astype(np.int64)
    if not params.hand_check_points:
        return Pick(candidates=cands, scores=scores, top=np.argsort(-scores, kind="stable")[:k].astype(np.int64),
                    random=random)
    points = surface_points(cands.vertices, cands.faces, params.hand_check_points, rng)
    clear = ~hand_hits(points, cands.T_tcp, hand_boxes(load_gripper(model.gripper)))
    # ranked: the clear candidates by score, then (only if fewer than k are clear) the others by score
    order = np.argsort(-scores, kind="stable")
    top = np.concatenate([order[clear[order]], order[~clear[order]]])[:k].astype(np.int64)
    ids = np.flatnonzero(clear)
    random_clear = np.sort(rng.choice(ids, size=min(k, len(ids)), replace=False)).astype(np.int64)
    return Pick(candidates=cands, scores=scores, top=top, random=random, clear=clear, random_clear=random_clear)


def hand_hits(points: np.ndarray, T_tcp: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """``(n,) bool``: whether any of ``points (p, 3)`` (object frame, m) lies inside any of the open hand's
    ``boxes (b, 2, 3)`` (lowest and highest corners, TCP frame) at each pose of ``T_tcp (n, 4, 4)``."""
    out = np.zeros(len(T_tcp), dtype=bool)
    for i, T in enumerate(np.asarray(T_tcp, dtype=np.float64)):
        local = (points - T[:3, 3]) @ T[:3, :3]
        out[i] = any(np.any(np.all((local >= lo) & (local <= hi), axis=1)) for lo, hi in boxes)
    return out


def simulate_pick(result: Pick, gripper: str, params: PickParams, *, jobs: int = 1,
                  cache_dir: str | Path | None = None) -> dict[str, Any]:
    """Roll out the top and the random group (``acronym`` protocol, free space) and report their success rates.

    Returns
    -------
    dict
        ``top_success``, ``random_success`` (fractions held), ``top_firm``, ``random_firm`` (fractions held
        firmly), ``density``, ``friction`` (of the rollouts), ``n_top``, ``n_random``, ``top_outcomes``,
        ``random_outcomes`` (outcome codes, in the groups' order), ``candidates``, ``mesh``, ``scale``, ``gripper``,
        ``top_scores``, ``random_scores``; with the hand check also ``clear_candidates``, ``random_clear_success``
        (held, of ``k`` drawn from the clear candidates), ``random_clear_outcomes``.
    """
    from graspgen.sim.protocols import Outcome
    from graspgen.workflows.evaluate import evaluate_grasps
    from graspgen.workflows.evaluate_settings import EvaluateParams

    c = result.candidates
    extra = result.random_clear if result.random_clear is not None else np.zeros(0, np.int64)
    both = np.concatenate([result.top, result.random, extra])
    table = evaluate_grasps(c.mesh_path, c.scale, c.T_tcp[both], c.width[both], gripper,
                            EvaluateParams(friction=params.friction, density=params.density,
                                           max_extent=params.max_extent),
                            protocol="acronym", jobs=jobs, cache_dir=cache_dir)
    outcome = table.column("outcome").to_numpy().astype(int)
    firm = table.column("firm").to_numpy(zero_copy_only=False).astype(bool)
    k, m = len(result.top), len(result.top) + len(result.random)
    top, random, clear = outcome[:k], outcome[k:m], outcome[m:]
    checked = {} if result.clear is None else {
        "clear_candidates": int(result.clear.sum()), "random_clear_success": float(np.mean(clear == Outcome.SUCCESS))
        if len(clear) else None, "random_clear_outcomes": clear.tolist()}
    return {
        "top_success": float(np.mean(top == Outcome.SUCCESS)),
        "random_success": float(np.mean(random == Outcome.SUCCESS)),
        "top_firm": float(np.mean(firm[:k])),
        "random_firm": float(np.mean(firm[k:m])),
        "density": params.density,
        "friction": params.friction,
        "n_top": int(k),
        "n_random": int(len(random)),
        "top_outcomes": top.tolist(),
        "random_outcomes": random.tolist(),
        "top_scores": result.scores[result.top].tolist(),
        "random_scores": result.scores[result.random].tolist(),
        "candidates": int(len(c.width)),
        "mesh": str(c.mesh_path),
        "scale": c.scale,
        "gripper": str(gripper),
        **checked,
    }
