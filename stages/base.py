"""What every stage of this project shares."""

from __future__ import annotations

from graspgen.errors import GraspGenError
from pipeline.stage import Stage


class GraspStage(Stage):
    """A pipeline stage that runs the grasp library: the library's errors are bad input, reported in one line."""

    user_errors = (GraspGenError,)
