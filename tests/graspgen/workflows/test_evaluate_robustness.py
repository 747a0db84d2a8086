"""Tests of the evaluate path's robustness (`evaluate_grasps(robustness=...)`, `gen evaluate --robustness N`) and of
`gen show rollout --grasps FILE --index I`: perturbed copies of external grasps, on a box whose geometry says which
grasps are robust."""

from __future__ import annotations

import json
import math

import h5py
import numpy as np
import pyarrow.parquet as pq
import pytest
import trimesh
from PIL import Image
from typer.testing import CliRunner

from graspgen.grippers import load_gripper
from graspgen.io.files import write_parquet
from graspgen.quality.epsilon import EpsilonParams
from graspgen.quality.perturbation import DRAWS_PER_COPY, RobustnessParams
from graspgen.workflows.evaluate import evaluate_grasps
from graspgen.workflows.evaluate_columns import METADATA_KEY, ROBUSTNESS_FIELDS
from graspgen.workflows.evaluate_settings import EvaluateParams
from graspgen.workflows.evaluation_world import evaluation_world
from graspgen.workflows.robustness import grasp_robustness
from graspgen_cli.app import app

PANDA_TCP = 0.1034  # m, hand base -> TCP along z (ACRONYM's convention)
BOX = (0.05, 0.06, 0.08)  # m, extents along the mesh x, y, z: the top face is at z = +0.04
N = 20
PARAMS = EvaluateParams(friction=0.8, mass=0.2)
runner = CliRunner()


pytestmark = pytest.mark.usefixtures("no_mujoco_log_in_repo")


def tcp(approach, closing, position) -> np.ndarray:
    """(4, 4) TCP pose from its approach (z) and closing (x) axes and origin (m), object frame."""
    z, x = np.asarray(approach, float), np.asarray(closing, float)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, np.cross(z, x), z, position
    return T


# From above, closing across the 50 mm x faces: with the TCP 1 cm below the top face the pads hold the box over
# their whole height, and a 5 mm / 5 deg error changes nothing; with the TCP 8 mm above the top face only the pads'
# lower edge reaches the box (a millimetre higher and they close on air), so about half of the copies, those raised
# along the approach axis, close on air. From the side, across the 60 mm y faces: the box is held, but the open
# fingers pass close to it, so a turned copy may touch it at placement (left out of grip_robustness).
CENTRED = tcp([0, 0, -1], [1, 0, 0], [0, 0, 0.03])
EDGE = tcp([0, 0, -1], [1, 0, 0], [0, 0, 0.048])
SIDE = tcp([-1, 0, 0], [0, 1, 0], [0, 0, 0.01])
MISS = tcp([0, 0, -1], [1, 0, 0], [0.3, 0, 0.03])  # 30 cm away: closes on air (3), no copies


@pytest.fixture(scope="module")
def box(tmp_path_factory):
    path = tmp_path_factory.mktemp("box") / "box.obj"
    trimesh.creation.box(extents=BOX).export(path)
    return path


@pytest.fixture(scope="module")
def labelled(box):
    T = np.stack([CENTRED, EDGE, SIDE, MISS])
    return evaluate_grasps(box, 1.0, T, None, "panda", PARAMS, protocol="acronym",
                           robustness=RobustnessParams(num_perturbations=N), jobs=1)


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """Wilson score interval, written out here from its textbook form (Wilson 1927; Agresti and Coull 1998)."""
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = (z / (1 + z * z / n)) * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    return centre - half, centre + half


def test_a_centred_grasp_is_robust_and_an_edge_grasp_is_not(labelled):
    rows = labelled.to_pylist()
    assert [r["outcome"] for r in rows] == [5, 5, 5, 3]
    centred, edge, side, miss = rows
    assert centred["robustness"] >= 0.9
    assert edge["robustness"] <= 0.5
    # The intervals of 20 copies already separate the two.
    assert centred["robustness_lo"] > edge["robustness_hi"]
    # The edge copies fail by closing on air (3), not by collisions: the hand got there and found too little box.
    assert edge["copy_outcomes"].count(3) >= N // 4
    # No nominal success, no copies: NaN, not 0 ("tried and failed" was not measured).
    assert miss["robustness_n"] == 0 and miss["copy_outcomes"] == [] and math.isnan(miss["robustness"])
    assert math.isnan(miss["grip_robustness"]) and math.isnan(miss["robustness_lo"])
    for row in (centred, edge, side):
        copies = np.array(row["copy_outcomes"])
        successes, grip = int(np.sum(copies == 5)), int(np.sum(np.isin(copies, (3, 4, 5))))
        assert row["robustness_n"] == len(copies) == N and row["robustness_successes"] == successes
        assert row["robustness"] == pytest.approx(successes / N)
        assert (row["robustness_lo"], row["robustness_hi"]) == pytest.approx(wilson(successes, N), abs=1e-12)
        assert row["grip_robustness"] == pytest.approx(successes / grip)
        assert (row["grip_robustness_lo"], row["grip_robustness_hi"]) == pytest.approx(wilson(successes, grip),
                                                                                        abs=1e-12)
    assert labelled.schema.names[-len(ROBUSTNESS_FIELDS):] == [f.name for f in ROBUSTNESS_FIELDS]
    meta = json.loads(labelled.schema.metadata[METADATA_KEY.encode()])
    assert meta["robustness"]["num_perturbations"] == N and isinstance(meta["robustness_seed"], int)


def test_the_copies_are_the_robustness_stages(labelled, box):
    """The same draws (layout (grasps, N, DRAWS_PER_COPY) from the recorded seed) through the robustness stage's own
    grasp_robustness in the evaluate world give the same copies: one perturbation model, not two."""
    meta = json.loads(labelled.schema.metadata[METADATA_KEY.encode()])
    T = np.stack([CENTRED, EDGE, SIDE, MISS])
    draws = np.random.default_rng(meta["robustness_seed"]).standard_normal((len(T), N, DRAWS_PER_COPY))
    world = evaluation_world(box, 1.0, T, None, "panda", PARAMS, protocol="acronym")
    row = 1  # the edge grasp: the one whose copies differ most
    stage = grasp_robustness(world.simulator(), world.T_world[row], float(world.width[row]), world.target_body,
                             world.geometry, PARAMS.friction, draws[row], RobustnessParams(num_perturbations=N),
                             EpsilonParams(), load_gripper("panda"))
    assert stage.outcomes.tolist() == labelled.column("copy_outcomes")[row].as_py()


def test_labels_do_not_depend_on_jobs_and_the_seed_on_the_poses(labelled, box, tmp_path):
    T = np.stack([CENTRED, EDGE, SIDE, MISS])
    two = evaluate_grasps(box, 1.0, T, None, "panda", PARAMS, protocol="acronym",
                          robustness=RobustnessParams(num_perturbations=N), jobs=2)
    write_parquet(tmp_path / "one.parquet", labelled)
    write_parquet(tmp_path / "two.parquet", two)
    assert (tmp_path / "one.parquet").read_bytes() == (tmp_path / "two.parquet").read_bytes()
    # The seed comes from the grasps and settings: other poses or other noise, another seed.
    seeds = set()
    for poses, noise in ((T[:2], N), (T, 5)):
        table = evaluate_grasps(box, 1.0, poses, None, "panda", PARAMS, protocol="acronym",
                                robustness=RobustnessParams(num_perturbations=noise))
        seeds.add(json.loads(table.schema.metadata[METADATA_KEY.encode()])["robustness_seed"])
    seeds.add(json.loads(labelled.schema.metadata[METADATA_KEY.encode()])["robustness_seed"])
    assert len(seeds) == 3
    with pytest.raises(ValueError, match="robustness: must be a RobustnessParams"):
        evaluate_grasps(box, 1.0, T[:1], None, "panda", PARAMS, robustness=5)
    with pytest.raises(ValueError, match="rng: must be a numpy.random.Generator"):
        evaluate_grasps(box, 1.0, T[:1], None, "panda", PARAMS, robustness=RobustnessParams(), rng=7)


@pytest.fixture
def acronym_file(tmp_path):
    """The box in millimetres and an ACRONYM file (written with h5py) of the centred grasp (FleX label 1) and the
    miss (0), as hand-base poses."""
    (tmp_path / "meshes").mkdir()
    trimesh.creation.box(extents=[1000 * e for e in BOX]).export(tmp_path / "meshes" / "box.obj")
    T_tcp = np.stack([CENTRED, MISS])
    T_base = T_tcp.copy()
    T_base[:, :3, 3] -= PANDA_TCP * T_tcp[:, :3, 2]
    path = tmp_path / "Box_0.001.h5"
    with h5py.File(path, "w") as f:
        f["grasps/transforms"] = T_base
        f["grasps/qualities/flex/object_in_gripper"] = np.array([1, 0])
        f["object/file"] = np.bytes_("meshes/box.obj")
        f["object/scale"] = 0.001
        f["object/mass"] = 0.2
        f["object/friction"] = 0.8
        f["gripper/type"] = np.bytes_("franka_panda")
    return path


def gen(*args):
    result = runner.invoke(app, [str(a) for a in args])
    return result, " ".join(result.output.split())


def test_gen_evaluate_robustness_end_to_end(acronym_file, tmp_path):
    out = tmp_path / "labels.parquet"
    result, text = gen("evaluate", "--grasps", acronym_file, "--mesh-root", tmp_path, "--gripper", "panda", "--out",
                       out, "--robustness", 4)
    assert result.exit_code == 0, result.output
    assert "robustness: 4 copies of 1 successes; mean robustness" in text
    table = pq.read_table(out)
    assert table.column("outcome").to_pylist() == [5, 3]
    assert table.column("robustness_n").to_pylist() == [4, 0]
    assert len(table.column("copy_outcomes")[0].as_py()) == 4 and table.column("copy_outcomes")[1].as_py() == []
    assert table.column("reference_success").to_pylist() == [1, 0]
    plain, _ = gen("evaluate", "--grasps", acronym_file, "--mesh-root", tmp_path, "--gripper", "panda", "--out",
                   tmp_path / "plain.parquet")
    assert plain.exit_code == 0 and "robustness" not in pq.read_table(tmp_path / "plain.parquet").column_names
    bad, text = gen("evaluate", "--grasps", acronym_file, "--mesh-root", tmp_path, "--gripper", "panda", "--out",
                    out, "--robustness", -1)
    assert bad.exit_code == 2 and "--robustness" in text


def test_gen_show_rollout_of_an_external_grasp(acronym_file, tmp_path):
    png = tmp_path / "held.png"
    result, text = gen("show", "rollout", "--grasps", acronym_file, "--mesh-root", tmp_path, "--index", 0, "-o", png,
                       "-n", 5)
    assert result.exit_code == 0, result.output
    assert result.stdout.strip().endswith("held.png")
    # The outcome gen evaluate gives the grasp (acronym protocol, the file's gripper): success.
    assert "outcome 5 success (file label: held); 5 frames" in text
    with Image.open(png) as image:
        assert image.text["frames"] == "5" and image.text["outcome"] == "5"
        assert "Box_0.001.h5 grasp 0 (acronym protocol): success (5)" in image.text["title"]
        assert "file label: held" in image.text["title"]
        pixels = np.asarray(image.convert("RGB").crop((4, 22, 4 + 320, 22 + 240))).reshape(-1, 3)
        assert len(np.unique(pixels, axis=0)) > 50  # rendered, not blank
    miss, text = gen("show", "rollout", "--grasps", acronym_file, "--mesh-root", tmp_path, "--index", 1, "-o",
                     tmp_path / "miss.png", "--protocol", "table")
    assert miss.exit_code == 0 and "outcome 3 no_contact_established (file label: lost)" in text, miss.output
    for args, message in (
        (("--index", 2), "--index: 2 is out of range; "),
        ((), "--index: which grasp of --grasps to show"),
        (("scene_000000", "--index", 0), "give either SCENE_ID GRASP_ID or --grasps FILE --index I, not both"),
    ):
        bad, text = gen("show", "rollout", "--grasps", acronym_file, "--mesh-root", tmp_path, *args, "-o",
                        tmp_path / "x.png")
        assert bad.exit_code == 2 and message in text, (args, text)
    bare, text = gen("show", "rollout")
    assert bare.exit_code == 2 and "give SCENE_ID GRASP_ID (or --grasps FILE --index I)" in text


def test_after_closing_frames_spend_the_frames_on_the_shake():
    from graspgen.viz.evaluate_movie import after_closing_frames
    from graspgen.viz.rollout_movie import Frame

    def frames(phases):
        out = []
        for phase, count in phases:
            out += [Frame(phase, 10 * len(out), 0.02 * len(out), np.zeros(1)) for _ in range(count)]
        return out

    shaken = frames([("placement", 1), ("closing", 10), ("shaking", 30), ("holding", 5)])
    picked = after_closing_frames(shaken, 6)
    assert [f.phase for f in picked] == ["placement", "closing", "shaking", "shaking", "shaking", "holding"]
    assert picked[1] is shaken[10] and picked[2] is shaken[11] and picked[-1] is shaken[-1]
    assert [f.step for f in picked] == sorted(f.step for f in picked)
    # Ended while closing (no contact): the frames are thinned over the whole rollout.
    closed = frames([("placement", 1), ("closing", 10)])
    assert after_closing_frames(closed, 4)[0] is closed[0] and after_closing_frames(closed, 4)[-1] is closed[-1]
    assert len(after_closing_frames(closed, 4)) == 4
