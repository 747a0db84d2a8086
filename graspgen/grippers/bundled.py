"""The grippers bundled with the library: their files under ``assets/grippers`` and those files' digests.

Plain data, imported by :mod:`graspgen.grippers.files` (for messages) and :mod:`graspgen.grippers.registry`.
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["GRIPPERS_DIR", "BUNDLED_FILES", "BUNDLED_DIGESTS", "bundled_names"]

#: The folder of the bundled gripper files.
GRIPPERS_DIR = Path(__file__).resolve().parents[2] / "assets" / "grippers"
#: Registry name -> gripper file, relative to :data:`GRIPPERS_DIR`.
BUNDLED_FILES = {"box_jaw": "box_jaw.yaml", "panda": "panda/panda.yaml", "robotiq_2f85": "robotiq_2f85.yaml",
                 "robotiq_2f85_mesh": "robotiq_2f85/robotiq_2f85_mesh.yaml"}
#: sha256 (first 16 hex digits) of every file the bundled grippers are read from, relative to GRIPPERS_DIR. The
#: bundled grippers are part of the library, so their files must count as code: a stage's content key holds the
#: digest of this module (every user of a bundled gripper imports it), and with it these digests, so editing a
#: bundled file (and then this table, which tests/graspgen/grippers/test_grippers.py checks) re-runs the stages
#: that use grippers, with the same random draws.
BUNDLED_DIGESTS = {
    "box_jaw.yaml": "0aad5e0055e1f959",
    "panda/finger.obj": "67373fdf9def1084",
    "panda/hand.obj": "feaab1d7eddd6fcb",
    "panda/pad.obj": "88587d01d351de87",
    "panda/panda.yaml": "560bbd1544ce8738",
    "robotiq_2f85/airo/robotiq_arg2f_85_inner_finger.obj": "f6507cef254ba4a1",
    "robotiq_2f85/airo/robotiq_arg2f_85_inner_knuckle.obj": "81dcdd59590b823a",
    "robotiq_2f85/airo/robotiq_arg2f_85_outer_finger.obj": "135d80498c0bdee5",
    "robotiq_2f85/airo/robotiq_arg2f_85_outer_knuckle.obj": "bd3a4fb67e22d904",
    "robotiq_2f85/airo/robotiq_arg2f_base_link.obj": "912592cfa4056b44",
    "robotiq_2f85/driver.obj": "342523646af15430",
    "robotiq_2f85/finger.obj": "49b214ca3971d013",
    "robotiq_2f85/follower.obj": "71cda5c7693f5f7a",
    "robotiq_2f85/palm.obj": "bfdebd31d584551f",
    "robotiq_2f85/robotiq_2f85_mesh.yaml": "555855ac7388c2e0",
    "robotiq_2f85.yaml": "f7cae12808cecc68",
}


def bundled_names() -> str:
    """The bundled grippers' names, sorted, comma-separated (for messages)."""
    return ", ".join(sorted(BUNDLED_FILES))
