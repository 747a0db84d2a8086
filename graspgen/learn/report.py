"""Scores against labels: pooled ROC-AUC and average precision, per-object AUC, top-k. Numpy only (exact rank
formulas, tested against slow references)."""

from __future__ import annotations

import numpy as np
from scipy.stats import rankdata

__all__ = ["TOP_K", "average_precision", "roc_auc", "score_report", "top_k_success"]

TOP_K = 10
"""k of the top-k success rate."""


def roc_auc(label: np.ndarray, score: np.ndarray) -> float | None:
    """ROC-AUC = P(score of a positive > a negative's), ties count 1/2 (Mann-Whitney U); None with one class."""
    y = np.asarray(label, dtype=bool)
    pos, neg = int(y.sum()), int((~y).sum())
    if pos == 0 or neg == 0:
        return None
    r = rankdata(np.asarray(score, dtype=np.float64))
    return float((r[y].sum() - pos * (pos + 1) / 2) / (pos * neg))


def average_precision(label: np.ndarray, score: np.ndarray) -> float | None:
    """Average precision as sklearn defines it: sum over distinct thresholds (descending) of (R_n - R_{n-1}) P_n;
    None without positives."""
    y = np.asarray(label, dtype=bool)
    s = np.asarray(score, dtype=np.float64)
    if not y.any():
        return None
    order = np.argsort(-s, kind="stable")
    y, s = y[order], s[order]
    last = np.r_[np.flatnonzero(np.diff(s) != 0), len(s) - 1]  # last index of each tied group
    tp = np.cumsum(y)[last]
    precision = tp / (last + 1)
    recall = tp / y.sum()
    return float(np.sum(np.diff(np.r_[0.0, recall]) * precision))


def top_k_success(label: np.ndarray, score: np.ndarray, k: int = TOP_K) -> float | None:
    """Success rate of the ``k`` best-scored grasps, ties among equal scores broken fairly: the expected rate over
    every order of the tied grasps equally likely.

    Groups of equal score are taken best first; the group that straddles the k-th place gives its remaining
    ``r`` places ``r * positives / size`` positives (the mean of a random draw of ``r`` of its grasps). So a
    constant score gives exactly the set's success rate, whatever order the grasps came in (breaking ties by
    trial order would reward whatever order the sampler tried them in).

    Parameters
    ----------
    label : (m,) bool
    score : (m,) float
    k : int
        Places; ``min(k, m)`` are taken.

    Returns
    -------
    float or None
        In [0, 1]; None when ``m`` is 0.
    """
    y = np.asarray(label, dtype=bool).reshape(-1)
    s = np.asarray(score, dtype=np.float64).reshape(-1)
    take = min(int(k), len(y))
    if take <= 0:
        return None
    levels, inverse = np.unique(-s, return_inverse=True)  # best score first
    size = np.bincount(inverse, minlength=len(levels))
    pos = np.bincount(inverse, weights=y.astype(np.float64), minlength=len(levels))
    before = np.r_[0, np.cumsum(size)[:-1]]
    places = np.clip(take - before, 0, size)  # how many of each group the top-k holds
    return float(np.sum(places * pos / size) / take)


def score_report(sets, scores) -> dict:
    """The held-out figures of ``scores`` (one (m,) array per set) against the sets' labels (contract layout)."""
    labels = [np.asarray(s.label, dtype=bool) for s in sets]
    scores = [np.asarray(x, dtype=np.float64).reshape(-1) for x in scores]
    y, p = np.concatenate(labels), np.concatenate(scores)
    per = []
    top, rand = [], []
    for s, yi, pi in zip(sets, labels, scores):
        per.append({"name": s.name, "n": int(len(yi)), "positives": int(yi.sum()), "auc": roc_auc(yi, pi)})
        if len(yi):
            top.append(top_k_success(yi, pi))  # ties at their expected value over a random order
            rand.append(float(yi.mean()))
    aucs = [o["auc"] for o in per if o["auc"] is not None]
    return {"auc": roc_auc(y, p), "ap": average_precision(y, p), "base_rate": float(y.mean()) if len(y) else None,
            "n": int(len(y)), "per_object": per, "mean_object_auc": float(np.mean(aucs)) if aucs else None,
            "top_k": {"k": TOP_K, "success": float(np.mean(top)) if top else None,
                      "random": float(np.mean(rand)) if rand else None, "objects": len(top)}}
