import os
import sys
from pathlib import Path

# The toy pipeline module must be importable in joblib worker processes too.
sys.path.insert(0, str(Path(__file__).parent))
os.environ["PYTHONPATH"] = os.pathsep.join(filter(None, [str(Path(__file__).parent), os.environ.get("PYTHONPATH")]))
from graspgen.sim.gl import select_backend  # noqa: E402

select_backend()  # before any test module imports mujoco (MUJOCO_GL is read once); workers inherit the choice
