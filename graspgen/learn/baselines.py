"""Baselines scored on the same held-out objects as the network. Needs scikit-learn.

* ``base_rate``: every grasp scored with the training grasps' success rate (AUC 0.5 by construction).
* ``object_rate``: every grasp of a held-out object scored with that object's own success rate: an oracle that
  knows each held-out object's rate (pooled AUC > 0.5 from between-object differences alone; per-object AUC 0.5).
* ``gbt``: sklearn HistGradientBoostingClassifier (seeded) on pooled statistics of the same features
  (:func:`pooled_features`), not on the raw point list (whose row order carries no meaning across grasps).
"""

from __future__ import annotations

import numpy as np

from graspgen.learn.features import FeatureParams, set_features
from graspgen.learn.report import score_report

__all__ = ["baselines", "pooled_features"]


def pooled_features(points: np.ndarray, width: np.ndarray, num_points: int | None = None) -> np.ndarray:
    """(m, 29) float64 per grasp: width; fraction of the K closing rows inside the closing volume and of them near
    it; inside points with x < 0 and x > 0 (fractions); of the inside points mean, std, min, max of x, y, z; of the
    near points mean, min, max of x, y, z (0 where there are none); of the hand rows, the fractions inside the hand
    and near it (0 without hand rows). ``points``: (m, K + K_h, 5) :func:`grasp_features` rows; ``num_points``: K
    (None: every row is a closing row)."""
    k = points.shape[1] if num_points is None else int(num_points)
    hand_rows = points[:, k:]
    points = points[:, :k]
    xyz, inside = points[..., :3].astype(np.float64), points[..., 3] > 0.5
    near = np.any(points != 0.0, axis=2)
    k = points.shape[1]

    def stats(mask, funcs):
        cols = []
        n = mask.sum(axis=1)
        for f in funcs:
            if f == "mean":
                v = (xyz * mask[..., None]).sum(1) / np.maximum(n, 1)[:, None]
            elif f == "std":
                mean = (xyz * mask[..., None]).sum(1) / np.maximum(n, 1)[:, None]
                v = np.sqrt((((xyz - mean[:, None]) ** 2) * mask[..., None]).sum(1) / np.maximum(n, 1)[:, None])
            elif f == "min":
                v = np.where(mask[..., None], xyz, np.inf).min(1)
            else:
                v = np.where(mask[..., None], xyz, -np.inf).max(1)
            cols.append(np.where(n[:, None] > 0, v, 0.0))
        return cols

    left = (inside & (xyz[..., 0] < 0)).sum(1) / k
    right = (inside & (xyz[..., 0] > 0)).sum(1) / k
    cols = [width[:, None], inside.mean(1)[:, None], near.mean(1)[:, None], left[:, None], right[:, None]]
    cols += stats(inside, ("mean", "std", "min", "max")) + stats(near, ("mean", "min", "max"))
    in_hand = (hand_rows[..., 4] > 0.5).mean(1) if hand_rows.shape[1] else np.zeros(len(points))
    near_hand = np.any(hand_rows != 0.0, axis=2).mean(1) if hand_rows.shape[1] else np.zeros(len(points))
    cols += [in_hand[:, None], near_hand[:, None]]
    return np.concatenate(cols, axis=1)


def baselines(train, valid, feature_params: FeatureParams | None, seed: int) -> dict:
    """{"base_rate", "object_rate", "gbt"}: a :func:`graspgen.learn.report.score_report` each, on ``valid``."""
    from graspgen.learn import require_torch

    require_torch()  # scikit-learn comes with the same extra
    from sklearn.ensemble import HistGradientBoostingClassifier

    from graspgen.grippers import load_gripper

    feature_params = feature_params or FeatureParams()
    y = np.concatenate([np.asarray(s.label, bool) for s in train])
    rate = float(y.mean())
    out = {"base_rate": score_report(valid, [np.full(len(s.label), rate) for s in valid]),
           "object_rate": score_report(valid, [np.full(len(s.label), float(np.mean(s.label)) if len(s.label) else 0.0)
                                               for s in valid])}
    spec = load_gripper(train[0].gripper)
    X = pooled_features(*set_features(train, spec, feature_params, seed), feature_params.num_points)
    gbt = HistGradientBoostingClassifier(random_state=seed).fit(X, y)
    scores = []
    for s in valid:
        Xv = pooled_features(*set_features([s], spec, feature_params, seed), feature_params.num_points)
        scores.append(gbt.predict_proba(Xv)[:, 1] if len(Xv) else np.zeros(0))
    out["gbt"] = score_report(valid, scores)
    return out
