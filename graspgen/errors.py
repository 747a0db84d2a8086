"""The grasp library's one error family.

Everything the library raises on purpose is a :class:`GraspGenError`, so a caller catches all of it in one place
and the ``gen`` command prints it in one line, without a traceback. Settings errors are also ``ValueError``\\ s,
so a config loader that prefixes the key path (``grasps.gripper: ...``) handles them like any bad value.
"""

from __future__ import annotations


class GraspGenError(Exception):
    """Base class of every error the grasp library raises on purpose."""


class SettingsError(GraspGenError, ValueError):
    """A setting is out of range or names something unknown. The message starts with the setting's name and, for
    a name, lists the valid choices: ``gripper: unknown 'x'; choose one of: box_jaw, panda, robotiq_2f85``."""


class NotFoundError(GraspGenError, KeyError):
    """A name asked for is not there: a column, a scene, a grasp id, a body or joint of a model. Also a
    ``KeyError``, so ``except KeyError`` and ``dict``-like lookups keep working; the message lists what is there:
    ``no scene 'x' in out/dataset/scenes; scenes: scene_000000, scene_000001``."""

    def __str__(self) -> str:  # KeyError's own str() wraps the message in quotes
        return str(self.args[0]) if self.args else ""


class InputError(GraspGenError):
    """An input file (a mesh, a grasp file, a dataset) cannot be used. The message names the file and why."""


class SimulationError(GraspGenError):
    """A physics simulation cannot go on (a diverged state, an object that will not settle)."""


class RenderError(GraspGenError):
    """Images were asked for where no OpenGL back end is available."""


class MissingDependencyError(GraspGenError, ImportError):
    """An optional part of the library was used without its extra installed. The message names the install:
    ``graspgen.learn needs torch and scikit-learn, which are not installed: pip install -e '.[learn]' ...``."""
