"""The ``gen`` console script: the generic pipeline commands bound to this project's stages."""

from __future__ import annotations

import os

from pipeline.cli import build_app
from pipeline.scheduler import Project
from stages.config import Config
from stages.objects import ObjectsStage

# MuJoCo's renderer needs a headless GL backend on machines without a display; EGL works with Mesa.
os.environ.setdefault("MUJOCO_GL", "egl")

PROJECT = Project(name="gen", schema=Config, stages=(ObjectsStage(),))
"""The stages in their declared order; the scheduler sorts them by dependency."""

app = build_app(PROJECT)


def main() -> None:
    app()


if __name__ == "__main__":
    main()
