"""The grasp evaluator: a small PointNet (the 6-DOF GraspNet evaluator / PointNetGPD family). Needs torch.

Sizes: a shared per-point MLP 5 -> 64 -> 128 -> 256 (ReLU after each layer), a max-pool over the rows, the
width appended (257), a head 257 -> 128 -> 1 (ReLU between): 74,881 parameters at 5 channels. Lengths enter divided by
``length_scale`` (m; half the gripper's open width, so the closing volume spans about [-1, 1] along x).
"""

from __future__ import annotations

try:
    import torch
except ImportError:  # one clear error naming the install, not a bare ModuleNotFoundError
    from graspgen.learn import require_torch

    require_torch()
    raise
from torch import nn  # noqa: E402

__all__ = ["EvaluatorEnsemble", "PointNetEvaluator"]


class PointNetEvaluator(nn.Module):
    """forward(points (b, rows, channels) float32, width (b,) float32 m) -> (b,) success logits. A row is x, y, z
    (m) and ``channels - 3`` flags (:data:`graspgen.learn.features.CHANNELS`)."""

    def __init__(self, length_scale: float = 0.04, channels: int = 5) -> None:
        super().__init__()
        self.length_scale = float(length_scale)
        self.point_mlp = nn.Sequential(nn.Linear(int(channels), 64), nn.ReLU(), nn.Linear(64, 128), nn.ReLU(),
                                       nn.Linear(128, 256), nn.ReLU())
        self.head = nn.Sequential(nn.Linear(257, 128), nn.ReLU(), nn.Linear(128, 1))

    def forward(self, points: torch.Tensor, width: torch.Tensor) -> torch.Tensor:
        xyz = points[..., :3] / self.length_scale
        h = self.point_mlp(torch.cat([xyz, points[..., 3:]], dim=-1)).amax(dim=1)
        return self.head(torch.cat([h, (width / self.length_scale)[:, None]], dim=1)).squeeze(1)


class EvaluatorEnsemble(nn.Module):
    """Members trained from independent draws on the same grasps (a deep ensemble, Lakshminarayanan et al. 2017).

    forward(points (b, rows, channels) float32, width (b,) float32 m) -> (b,) logits of the members' mean success
    probability, computed in log space so that confident members do not round to a tie at 1.0.
    """

    def __init__(self, members: list[PointNetEvaluator]) -> None:
        super().__init__()
        if len(members) < 2:
            raise ValueError(f"members: an ensemble needs at least 2, got {len(members)}")
        self.members = nn.ModuleList(members)
        self.length_scale = members[0].length_scale

    def forward(self, points: torch.Tensor, width: torch.Tensor) -> torch.Tensor:
        logits = torch.stack([m(points, width) for m in self.members])
        log_k = torch.log(torch.tensor(float(len(self.members)), dtype=logits.dtype))
        log_p = torch.logsumexp(nn.functional.logsigmoid(logits), dim=0) - log_k
        log_q = torch.logsumexp(nn.functional.logsigmoid(-logits), dim=0) - log_k
        return log_p - log_q
