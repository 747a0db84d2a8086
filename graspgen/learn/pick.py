"""Use a trained evaluator to pick grasps: sample candidates on a mesh, score them, simulate the best and random ones.

The end-to-end check of a model (``gen probe pick``): does ranking by the network's score pick grasps that hold
more often than picking at random?

1. :func:`sample_candidates`: the mesh is loaded, repaired and brought to metres as
   :func:`graspgen.workflows.prepare.prepare_object` does it (so the candidates are in the frame
   :func:`graspgen.workflows.evaluate.evaluate_grasps` rolls them out in), and antipodal candidates are drawn over the
   whole sphere as the object-grasps stage draws them (:func:`graspgen.geometry.antipodal.sample_antipodal` with
   ``approach="any"``: every call's candidates shuffled, calls repeated until ``n`` are there).
2. :func:`pick`: the model scores every candidate (:meth:`graspgen.learn.train.TrainedModel.score`); the top ``k``
   by score (ties by candidate index) and ``k`` drawn uniformly without replacement from all candidates.
3. :func:`simulate_pick`: both groups rolled out with :func:`graspgen.workflows.evaluate.evaluate_grasps` (the model's
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
from graspgen.learn.sources import ObjectGraspSet
from graspgen.validation import check, check_int, check_number, check_rng
from graspgen.workflows.object_grasps_settings import free_space_sampler

__all__ = ["Candidates", "Pick", "PickParams", "pick", "sample_candidates", "simulate_pick"]

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
    """``(k,) int64`` indices of the ``k`` best-scored candidates, best first."""
    random: np.ndarray
    """``(k,) int64`` indices of ``k`` candidates drawn uniformly without replacement."""


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
    top = np.argsort(-scores, kind="stable")[:k]
    random = np.sort(rng.choice(n, size=k, replace=False))
    return Pick(candidates=cands, scores=scores, top=top.astype(np.int64), random=random.astype(np.int64))


def simulate_pick(result: Pick, gripper: str, params: PickParams, *, jobs: int = 1,
                  cache_dir: str | Path | None = None) -> dict[str, Any]:
    """Roll out the top and the random group (``acronym`` protocol, free space) and report their success rates.

    Returns
    -------
    dict
        ``top_success``, ``random_success`` (fractions held), ``top_firm``, ``random_firm`` (fractions held
        firmly), ``density``, ``friction`` (of the rollouts), ``n_top``, ``n_random``, ``top_outcomes``,
        ``random_outcomes`` (outcome codes, in the groups' order), ``candidates``, ``mesh``, ``scale``, ``gripper``,
        ``top_scores``, ``random_scores``.
    """
    from graspgen.sim.protocols import Outcome
    from graspgen.workflows.evaluate import evaluate_grasps
    from graspgen.workflows.evaluate_settings import EvaluateParams

    c = result.candidates
    both = np.concatenate([result.top, result.random])
    table = evaluate_grasps(c.mesh_path, c.scale, c.T_tcp[both], c.width[both], gripper,
                            EvaluateParams(friction=params.friction, density=params.density,
                                           max_extent=params.max_extent),
                            protocol="acronym", jobs=jobs, cache_dir=cache_dir)
    outcome = table.column("outcome").to_numpy().astype(int)
    firm = table.column("firm").to_numpy(zero_copy_only=False).astype(bool)
    k = len(result.top)
    top, random = outcome[:k], outcome[k:]
    return {
        "top_success": float(np.mean(top == Outcome.SUCCESS)),
        "random_success": float(np.mean(random == Outcome.SUCCESS)),
        "top_firm": float(np.mean(firm[:k])),
        "random_firm": float(np.mean(firm[k:])),
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
    }
