import os
import sys
from pathlib import Path

import pytest

# The tests' helper modules (tests.toy_stages, tests.shapes, tests.paths) import from the repository root, here and
# in the joblib and dask worker processes. Never put tests/ itself on the path: its graspgen/ folder would shadow
# the library as a namespace package.
_REPO = str(Path(__file__).resolve().parent.parent)
sys.path.insert(0, _REPO)
os.environ["PYTHONPATH"] = os.pathsep.join(filter(None, [_REPO, os.environ.get("PYTHONPATH")]))
from graspgen.sim.gl import select_backend  # noqa: E402

select_backend()  # before any test module imports mujoco (MUJOCO_GL is read once); workers inherit the choice
# Grippers given as robot models cache their CoACD pieces in $GRASPGEN_GRIPPER_CACHE (graspgen.sim.gripper_derive):
# the tests' go to a temporary folder, not the user's ~/.cache, here and in the workers.
if "GRASPGEN_GRIPPER_CACHE" not in os.environ:
    import atexit
    import shutil
    import tempfile

    os.environ["GRASPGEN_GRIPPER_CACHE"] = tempfile.mkdtemp(prefix="graspgen-gripper-cache-")
    atexit.register(shutil.rmtree, os.environ["GRASPGEN_GRIPPER_CACHE"], True)


@pytest.fixture
def no_mujoco_log_in_repo(tmp_path, monkeypatch):
    """Run the test in its own temporary folder: MuJoCo writes MUJOCO_LOG.TXT into the cwd on errors, and it must
    not land in the repository. Used by the modules that simulate (``pytestmark = pytest.mark.usefixtures(...)``)."""
    monkeypatch.chdir(tmp_path)
