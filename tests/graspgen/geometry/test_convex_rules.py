"""Tests of the decision rules of graspgen.geometry.convex.convex_decomposition: the near-convex skip (judged by hull
slack), CoACD's pre-processing only for meshes that are not closed, the refinement only where the slack is over the
criterion, and the cache key's dependence on these settings. CoACD is replaced by a recorder where the rule, not the
decomposition, is under test."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import trimesh

from graspgen.errors import SettingsError
from graspgen.geometry import coacd_process
from graspgen.geometry.coacd_process import CoacdCrash
from graspgen.geometry.convex import CoacdParams, coacd_cache_key, convex_decomposition, hull_slack
from graspgen.geometry.repair import repair_mesh
from tests.shapes import l_shape

FAST = CoacdParams(threshold=0.05, resolution=300, mcts_iterations=20, mcts_nodes=10, preprocess_resolution=20)


def _fail(*args, **kwargs):
    raise AssertionError("CoACD must not run")


def notched_box(depth: float) -> trimesh.Trimesh:
    """A 0.1 x 0.06 x 0.04 m box with a 0.06 x 0.04 m notch ``depth`` deep cut into its top face (the notch's
    opening is 9.7 % of the hull's area)."""
    box = trimesh.creation.box((0.1, 0.06, 0.04))
    notch = trimesh.creation.box((0.06, 0.04, 2 * depth))
    notch.apply_translation((0.0, 0.0, 0.02))
    mesh, _ = repair_mesh(box.difference(notch, engine="manifold"))
    assert mesh.is_watertight and mesh.volume > 0
    return mesh



class Recorder:
    """Stands in for :func:`graspgen.geometry.coacd_process.run_coacd`: records each call's keyword arguments and
    returns given parts."""

    def __init__(self, parts):
        self.parts, self.calls = parts, []

    def __call__(self, vertices, faces, **kwargs):
        self.calls.append(kwargs)
        return [[np.asarray(v), np.asarray(f)] for v, f in self.parts]


def test_convex_box_skips_coacd_and_is_its_hull(monkeypatch):
    monkeypatch.setattr(coacd_process, "run_coacd", _fail)
    box = trimesh.creation.box((0.05, 0.07, 0.12))
    (part,) = convex_decomposition(box, FAST)
    hull = box.convex_hull
    assert trimesh.Trimesh(*part).volume == pytest.approx(hull.volume, rel=1e-12)
    np.testing.assert_array_equal(np.sort(part[0], axis=0), np.sort(hull.vertices, axis=0))


def test_shallow_notch_is_near_convex_its_hull_alone(monkeypatch):
    monkeypatch.setattr(coacd_process, "run_coacd", _fail)
    mesh = notched_box(0.0005)  # 0.5 mm deep: the hull bridges it by 0.5 mm at most, under the 1 mm criterion
    assert mesh.convex_hull.volume > mesh.volume * (1 + 1e-6)  # not convex in the exact sense
    (part,) = convex_decomposition(mesh, FAST)
    np.testing.assert_array_equal(np.sort(part[0], axis=0), np.sort(mesh.convex_hull.vertices, axis=0))
    assert hull_slack(mesh, [part], 4000, np.random.default_rng(0)).max == pytest.approx(0.0005, abs=1e-6)


def test_deep_notch_or_no_near_convex_rule_goes_to_coacd(monkeypatch):
    deep = notched_box(0.004)  # 4 mm: the hull's slack over the notch (> 5 % of its area) is over 1 mm
    hull = deep.convex_hull
    recorder = Recorder([(hull.vertices, hull.faces)])
    monkeypatch.setattr(coacd_process, "run_coacd", recorder)
    assert hull.volume <= 1.05 * deep.volume  # within the volume gate: the slack decides
    once = dataclasses.replace(FAST, refine_excess=0.0)  # the hull given back would be refined: one call each
    convex_decomposition(deep, once)
    assert len(recorder.calls) == 1
    convex_decomposition(notched_box(0.0005), CoacdParams(near_convex_excess=0.0, refine_excess=0.0))
    assert len(recorder.calls) == 2


def test_closed_mesh_skips_preprocessing_an_open_one_does_not(monkeypatch):
    mesh = l_shape()
    hull = mesh.convex_hull
    recorder = Recorder([(hull.vertices, hull.faces)])
    monkeypatch.setattr(coacd_process, "run_coacd", recorder)
    once = dataclasses.replace(FAST, refine_excess=0.0)  # the hull given back would be refined: one call each
    convex_decomposition(mesh, once)
    open_mesh = mesh.copy()
    open_mesh.update_faces(np.arange(len(open_mesh.faces)) != 0)  # one triangle missing: not watertight
    assert not open_mesh.is_watertight
    convex_decomposition(open_mesh, once)
    convex_decomposition(mesh, dataclasses.replace(once, preprocess_mode="on"))
    assert [c["preprocess_mode"] for c in recorder.calls] == ["off", "auto", "on"]


def test_a_crash_in_coacd_names_the_mesh(monkeypatch):
    def crashing(vertices, faces, **kwargs):
        raise CoacdCrash("CoACD crashed (SIGSEGV) while decomposing it")

    monkeypatch.setattr(coacd_process, "run_coacd", crashing)
    mesh = l_shape()
    mesh.metadata["file_name"] = "bowl_fca9.obj"
    with pytest.raises(CoacdCrash, match=r"^bowl_fca9.obj: CoACD crashed \(SIGSEGV\) while decomposing it$"):
        convex_decomposition(mesh, FAST)


def test_l_shape_is_decomposed_within_the_slack_criterion():
    mesh = l_shape()
    parts = convex_decomposition(mesh, FAST)
    assert len(parts) > 1
    slack = hull_slack(mesh, parts, 20_000, np.random.default_rng(3))
    assert slack.p95 <= FAST.slack_p95


def test_cavity_filled_but_not_reachable_is_not_refined(monkeypatch):
    """A closed hollow box: parts filling its inner void exceed its volume by far, yet stand out of its surface
    nowhere (the void is not reachable), so the refinement is not run."""
    outer = trimesh.creation.box((0.08, 0.08, 0.08))
    inner = trimesh.creation.box((0.07, 0.07, 0.07))
    inner.invert()
    shell = trimesh.util.concatenate([outer, inner])
    assert shell.is_watertight and shell.volume > 0
    hull = outer.convex_hull
    recorder = Recorder([(hull.vertices, hull.faces)])
    monkeypatch.setattr(coacd_process, "run_coacd", recorder)
    (part,) = convex_decomposition(shell, FAST)
    assert hull.volume / shell.volume - 1 > FAST.refine_excess
    assert len(recorder.calls) == 1


def _cup() -> trimesh.Trimesh:
    outer = trimesh.creation.cylinder(radius=0.03, height=0.06, sections=24)
    inner = trimesh.creation.cylinder(radius=0.027, height=0.06, sections=24)
    inner.apply_translation((0, 0, 0.004))
    cup, _ = repair_mesh(outer.difference(inner, engine="manifold"))
    return cup


def _slabs(mesh: trimesh.Trimesh, count: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """``count`` boxes stacked along z filling the mesh's bounding box: pieces that bridge every cavity."""
    low, high = mesh.bounds
    edges = np.linspace(low[2], high[2], count + 1)
    slabs = []
    for z0, z1 in zip(edges[:-1], edges[1:]):
        slab = trimesh.creation.box(bounds=[(low[0], low[1], z0), (high[0], high[1], z1)])
        slabs.append((slab.vertices, slab.faces))
    return slabs


@pytest.mark.parametrize("pieces, thresholds", [(1, [1, 4]), (2 * FAST.max_convex_hull, [1, 4]),
                                                (2 * FAST.max_convex_hull + 1, [1, 2]),
                                                (4 * FAST.max_convex_hull, [1, 2]),
                                                (4 * FAST.max_convex_hull + 1, [1])])
def test_cavity_bridged_from_outside_is_refined_by_a_cut_the_cap_can_keep(monkeypatch, pieces, thresholds):
    # Every piece rough (slabs filling the bounding box): the whole mesh is cut again. Up to twice max_convex_hull
    # pieces: at a quarter of the threshold; up to four times: at half; more: only merged again (a finer cut would
    # make more pieces than the cap keeps). CoACD never merges itself.
    cup = _cup()
    recorder = Recorder(_slabs(cup, pieces))
    monkeypatch.setattr(coacd_process, "run_coacd", recorder)
    monkeypatch.setattr(coacd_process, "run_coacd_each", _fail)
    convex_decomposition(cup, FAST)
    assert [FAST.threshold / c["threshold"] for c in recorder.calls] == pytest.approx(thresholds)
    assert all(c["merge"] is False and c["max_convex_hull"] == -1 for c in recorder.calls)


def test_refinement_keeps_the_parts_of_lowest_slack():
    cup = _cup()
    coarse = dataclasses.replace(FAST, threshold=0.2, max_convex_hull=4, refine_excess=0.0)
    bridged = convex_decomposition(cup, coarse)
    refined = convex_decomposition(cup, dataclasses.replace(coarse, refine_excess=0.01))
    rng = np.random.default_rng(0)
    assert hull_slack(cup, refined, 4000, rng).p95 < hull_slack(cup, bridged, 4000, rng).p95


def test_decomposition_is_deterministic_and_keyed_by_the_new_settings():
    mesh = l_shape()
    first = convex_decomposition(mesh, FAST)
    second = convex_decomposition(mesh, FAST)
    assert [(v.tobytes(), f.tobytes()) for v, f in first] == [(v.tobytes(), f.tobytes()) for v, f in second]
    keys = {coacd_cache_key(mesh, p) for p in (FAST, CoacdParams(preprocess_mode="auto"),
                                                  CoacdParams(slack_p95=2e-3), CoacdParams(near_convex_excess=0.0),
                                                  CoacdParams(slack_samples=1000), CoacdParams(free_merge_depth=0.0),
                                                  CoacdParams())}
    assert len(keys) == 7


@pytest.mark.parametrize("field, value", [("preprocess_mode", "sometimes"), ("slack_p95", 0.0),
                                          ("near_convex_excess", -0.1), ("slack_samples", 0),
                                          ("free_merge_depth", -1e-3)])
def test_bad_settings_name_their_field(field, value):
    with pytest.raises(SettingsError, match=field):
        CoacdParams(**{field: value})


def _notch_pieces(bridged: bool) -> list[tuple[np.ndarray, np.ndarray]]:
    """Pieces of :func:`notched_box` (4 mm deep): the bottom slab and the rim's two end strips, exact, and the rim's
    two side strips either as one piece bridging the notch (``bridged``) or exact."""
    def box(low, high):
        b = trimesh.creation.box(bounds=[low, high])
        return b.vertices, b.faces

    pieces = [box((-0.05, -0.03, -0.02), (0.05, 0.03, 0.016)), box((-0.05, -0.03, 0.016), (-0.03, 0.03, 0.02)),
              box((0.03, -0.03, 0.016), (0.05, 0.03, 0.02))]
    if bridged:
        return pieces + [box((-0.03, -0.03, 0.016), (0.03, 0.03, 0.02))]
    return pieces + [box((-0.03, -0.03, 0.016), (0.03, -0.02, 0.02)), box((-0.03, 0.02, 0.016), (0.03, 0.03, 0.02))]


def test_a_minority_of_rough_pieces_is_cut_again_alone(monkeypatch):
    """First cut: four pieces, one bridging the notch 4 mm deep (rough: a third of its surface stands over 1 mm out).
    Only the mesh inside it, the notch's two side strips, goes to CoACD again (which gives them back as two boxes
    here: CoACD 1.0.14 crashes on such boxes at fine thresholds), and the result meets the criterion."""
    mesh = notched_box(0.004)
    whole = Recorder(_notch_pieces(bridged=True))
    each = []

    def recording_each(requests):
        each.extend(requests)
        return [[(np.asarray(v), np.asarray(f)) for v, f in _notch_pieces(bridged=False)[3:]] for _ in requests]

    monkeypatch.setattr(coacd_process, "run_coacd", whole)
    monkeypatch.setattr(coacd_process, "run_coacd_each", recording_each)
    parts = convex_decomposition(mesh, FAST)
    assert len(whole.calls) == 1  # the first cut only: no cut of the whole mesh
    (request,) = each
    inside = trimesh.Trimesh(request[0], request[1])
    assert inside.volume == pytest.approx(2 * 0.06 * 0.01 * 0.004, rel=1e-6)
    # The same concavity in m as a whole-mesh cut at a quarter: relative to the strips' half extent, 0.03 m, not 0.05.
    assert request[2]["threshold"] == pytest.approx(FAST.threshold / 4 * 0.05 / 0.03)
    assert len(parts) == 5
    assert hull_slack(mesh, parts, 20_000, np.random.default_rng(3)).p95 <= 1e-6


def test_rough_pieces_that_crash_coacd_are_kept_and_the_whole_mesh_is_cut(monkeypatch):
    mesh = notched_box(0.004)
    whole = Recorder(_notch_pieces(bridged=True))
    monkeypatch.setattr(coacd_process, "run_coacd", whole)
    monkeypatch.setattr(coacd_process, "run_coacd_each",
                        lambda requests: [CoacdCrash("CoACD crashed (SIGSEGV) while decomposing it")] * len(requests))
    convex_decomposition(mesh, FAST)
    # The rough piece kept leaves the slack over the criterion: the whole mesh is cut again, at a quarter.
    assert [FAST.threshold / c["threshold"] for c in whole.calls] == pytest.approx([1, 4])


def test_exact_pieces_are_not_refined(monkeypatch):
    whole = Recorder(_notch_pieces(bridged=False))
    monkeypatch.setattr(coacd_process, "run_coacd", whole)
    monkeypatch.setattr(coacd_process, "run_coacd_each", _fail)
    assert len(convex_decomposition(notched_box(0.004), FAST)) == 5
    assert len(whole.calls) == 1


def test_a_refined_decomposition_starts_one_coacd_process(monkeypatch):
    import subprocess

    started = []
    popen = subprocess.Popen

    def counted(*args, **kwargs):
        started.append(args)
        return popen(*args, **kwargs)

    calls = []
    run_coacd_each = coacd_process.run_coacd_each

    def each(requests):
        calls.append(len(requests))
        return run_coacd_each(requests)

    monkeypatch.setattr(subprocess, "Popen", counted)
    monkeypatch.setattr(coacd_process, "run_coacd_each", each)
    coarse = dataclasses.replace(FAST, threshold=0.2, max_convex_hull=4, refine_excess=0.01)
    convex_decomposition(_cup(), coarse)
    assert sum(calls) >= 2  # the first cut and at least one refinement
    assert len(started) == 1


def test_the_mesh_inside_a_piece_is_the_same_bytes_every_time():
    """The rough pieces' meshes (manifold3d intersections) go to CoACD: they must not vary between runs."""
    from graspgen.geometry.convex import _mesh_inside
    from graspgen.geometry.part_merge import convex_part

    cup = _cup()
    piece = convex_part(np.array([[-0.04, -0.04, 0.0], [0.04, -0.04, 0.0], [-0.04, 0.04, 0.0], [0.04, 0.04, 0.0],
                                  [-0.04, -0.04, 0.05], [0.04, -0.04, 0.05], [-0.04, 0.04, 0.05],
                                  [0.04, 0.04, 0.05]]))
    first, second = _mesh_inside(cup, piece), _mesh_inside(cup, piece)
    assert first.is_watertight and 0 < first.volume < cup.volume
    assert first.vertices.tobytes() == second.vertices.tobytes() and first.faces.tobytes() == second.faces.tobytes()
    outside = convex_part(np.array([[1.0, 1, 1], [1.1, 1, 1], [1, 1.1, 1], [1, 1, 1.1]]))
    assert _mesh_inside(cup, outside) is None
