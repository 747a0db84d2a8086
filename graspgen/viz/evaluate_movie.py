"""Looking at an external grasp's rollout: one grasp of a grasp file (ACRONYM, Parquet poses) rolled out again in the
world of :func:`graspgen.workflows.evaluate.evaluate_grasps`, under its protocol, and filmed.

:func:`evaluated_rollout_movie` takes an :class:`graspgen.workflows.evaluation_world.EvaluationWorld` (from
:func:`graspgen.workflows.evaluation_world.evaluation_world`: the same prepared object, opening, support and protocol as
``gen evaluate``), rolls grasp ``index`` out in a fresh model of it (so the outcome is the one ``gen evaluate`` gives
that grasp: a rollout depends only on the model and its inputs, :mod:`graspgen.sim.lift`), records the state at every
rule check, keeps a few and renders them from the side
(:func:`graspgen.viz.rollout_movie.side_cameras`) in a second model of the world that also holds the object's visual
mesh (same joints; the physics model has only the convex parts). :func:`graspgen.viz.rollout_movie.save_movie` writes
the PNG strip or GIF. ``gen show rollout --grasps FILE --index I`` is the command line for it.

Frames (:func:`after_closing_frames`): the start and the end of closing, then the rest spent after closing, where the
label is decided (the shake of ``acronym``, the tugs of ``graspdatagen``, the lift and hold of ``table``), by
:func:`graspgen.viz.rollout_movie.pick_frames` (every phase end, then evenly in time); a rollout that ended before
closing did is thinned as a whole.
"""

from __future__ import annotations

from graspgen.errors import SettingsError
from graspgen.sim.gl import select_backend

select_backend()  # Rendering needs a headless GL backend; MuJoCo reads MUJOCO_GL when first imported.

from collections.abc import Sequence  # noqa: E402

from graspgen.sim.object_world import world_spec  # noqa: E402
from graspgen.sim.protocol_phases import protocol_of  # noqa: E402
from graspgen.sim.render import render_frames  # noqa: E402
from graspgen.validation import check_int  # noqa: E402
from graspgen.viz.rollout_movie import (  # noqa: E402
    Frame,
    RolloutMovie,
    pick_frames,
    record_rollout,
    side_cameras,
)
from graspgen.workflows.evaluation_world import EvaluationWorld  # noqa: E402

__all__ = ["after_closing_frames", "evaluated_rollout_movie"]

_FRAMING = 0.38
"""Camera distance (m) for objects up to ~15 cm across; larger objects are filmed from farther (4x their radius)."""


def evaluated_rollout_movie(
    world: EvaluationWorld,
    index: int,
    *,
    name: str = "",
    reference: int | None = None,
    n_frames: int = 8,
    size: tuple[int, int] = (320, 240),
) -> RolloutMovie:
    """Roll grasp ``index`` of ``world`` out again and render ``n_frames`` frames of it.

    Parameters
    ----------
    world : EvaluationWorld
        The evaluation world with the grasps (:func:`graspgen.workflows.evaluation_world.evaluation_world`).
    index : int
        The grasp, ``0 <= index < len(world.T_world)``.
    name : str
        What the title calls the grasp (e.g. the file name and the file's row of the grasp); default
        ``grasp <index>``.
    reference : int, optional
        The file's own label of the grasp (1 held, 0 lost; ACRONYM's FleX ``object_in_gripper``), named in the title.
    n_frames : int
        At most this many frames (:func:`after_closing_frames`).
    size : (width, height)
        Frame size, pixels.

    Returns
    -------
    RolloutMovie
        ``stored_outcome`` is None (an external file has no outcome code of ours).

    Raises
    ------
    ValueError
        ``index`` out of range (the message gives the range).
    """
    n = len(world.T_world)
    index = check_int("index", index, low=0)
    if index >= n:
        raise SettingsError(f"index: {index} is out of range; the grasps are 0..{n - 1}")
    T = world.T_world[index]
    body = world.target_body
    result, states = record_rollout(world.simulator(), T, float(world.width[index]), body)
    frames = after_closing_frames(states, n_frames)

    lift = world.world.lift
    rise = lift.lift_height if protocol_of(lift).lifts else 0.0
    distance = max(_FRAMING, 4.0 * world.geometry.torque_scale)
    camera = side_cameras(T, rise, width=size[0], height=size[1], distance=distance)[0]
    images = render_frames(world_spec(world.world, world.visual()), [f.qpos for f in frames], [camera])

    title = f"{name or f'grasp {index}'} ({lift.protocol} protocol): {result.name} ({result.code}), decided in " \
            f"{result.decided_in}"
    if reference is not None:
        title += f"; file label: {'held' if int(reference) == 1 else 'lost'}"
    labels = [f"{f.phase} t={f.time:.2f} s" for f in frames]
    return RolloutMovie(images, labels, title, result, None, True)


def after_closing_frames(frames: Sequence[Frame], n: int) -> list[Frame]:
    """At most ``n`` of ``frames`` (``n >= 1``), in time order, most of them after closing: the first frame, the
    last of the closing phase, then ``n - 2`` of the later frames by :func:`graspgen.viz.rollout_movie.pick_frames`
    (their first, every phase end, then evenly in time). Without later frames (the rollout ended while closing or
    before) or with ``n < 4``: :func:`graspgen.viz.rollout_movie.pick_frames` over all of them."""
    closing = [i for i, f in enumerate(frames) if f.phase == "closing"]
    if n < 4 or not closing or closing[-1] + 1 >= len(frames):
        return pick_frames(frames, n)
    end = closing[-1]
    return [frames[0], frames[end], *pick_frames(frames[end + 1:], n - 2)]
