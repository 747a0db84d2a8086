"""Small helpers shared by the engine (``pipeline``) and the grasp library (``graspgen``), below both.

It imports neither (an import-linter contract in ``pyproject.toml`` keeps it so) and nothing outside the standard
library: :mod:`shared_utils.atomic` (atomic file writes), :mod:`shared_utils.digest` (file hashes),
:mod:`shared_utils.keys` (content-key flags), :mod:`shared_utils.renames` (former names of settings).
"""
