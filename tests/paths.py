"""Folders the tests read from, wherever the test module sits under ``tests/``."""

from pathlib import Path

TESTS = Path(__file__).resolve().parent
"""The ``tests/`` folder."""

REPO = TESTS.parent
"""The repository root: ``configs/``, ``assets/``, ``docs/``."""
