"""The learnability probe's settings, :class:`ProbeParams` (numpy only: importing it never imports torch).

One class for the config section ``probe`` (the ``probe`` stage) and for :func:`graspgen.learn.probe.run_probe`.
"""

from __future__ import annotations

import dataclasses

from graspgen.learn.features import FeatureParams
from graspgen.validation import check, check_int, check_number

__all__ = ["ProbeParams"]


@dataclasses.dataclass(frozen=True)
class ProbeParams:
    """Settings of the learnability probe: config section ``probe`` of the ``probe`` stage, and what
    :func:`graspgen.learn.probe.run_probe` reads (all keys but ``enabled`` and ``seed``, which only the stage reads).

    Raises
    ------
    SettingsError
        A value out of range (the message names the key).
    """

    enabled: bool = True
    """Train the probe and publish its model and report with the dataset (needs torch and scikit-learn: ``pip
    install -e '.[learn]'``); false: the card says "Learnability: not run"."""
    valid_fraction: float = 0.3
    """Share of the objects held out for scoring, in (0, 1): an object is held out when the first 32 bits of
    sha256(salt + name), as a fraction of 2^32, are below it (so adding objects moves none)."""
    salt: str = "probe"
    """Text prefixed to each name before hashing: another salt, another split."""
    epochs: int = 10
    """Passes over the training grasps (>= 1). On the default config the probe task takes under a minute of one
    core at 10."""
    batch_size: int = 128
    """Grasps per batch (balanced: half successes, half failures)."""
    learning_rate: float = 1e-3
    """Adam's learning rate."""
    num_points: int = 64
    """Surface points per grasp nearest the closing region, in the TCP frame (the network's input; the 32 points
    nearest the hand's body come beside them, :class:`graspgen.learn.features.FeatureParams`)."""
    num_surface_points: int = 2048
    """Points sampled on each object's surface (area-weighted) that the per-grasp points are chosen from."""
    seed: int = 0
    """Another integer gives other training draws (initial weights, batches, surface points) on the same data: the
    spread of the scores over seeds is their noise. The draws come from the task's generator, which every key of
    this section (and ``run.seed``) seeds."""

    def __post_init__(self) -> None:
        check("enabled", isinstance(self.enabled, bool), "be true or false", self.enabled)
        object.__setattr__(self, "valid_fraction", check_number("valid_fraction", self.valid_fraction, low=0.0,
                                                                high=1.0, low_open=True, high_open=True))
        check("salt", isinstance(self.salt, str), "be a string", self.salt)
        for key in ("epochs", "batch_size", "num_points", "num_surface_points"):
            object.__setattr__(self, key, check_int(key, getattr(self, key), low=1))
        check("batch_size", self.batch_size % 2 == 0, "be even (half successes, half failures)", self.batch_size)
        check("num_surface_points", self.num_surface_points >= self.num_points,
              f"be >= num_points ({self.num_points})", self.num_surface_points)
        object.__setattr__(self, "learning_rate", check_number("learning_rate", self.learning_rate, low=0.0,
                                                               low_open=True))
        object.__setattr__(self, "seed", check_int("seed", self.seed, low=0))

    @property
    def features(self) -> FeatureParams:
        """The network's input: :class:`graspgen.learn.features.FeatureParams`."""
        return FeatureParams(num_surface_points=self.num_surface_points, num_points=self.num_points)
