"""The outcomes plot's per-object panel: one row per object up to OUTCOME_ROWS, then groups of objects whose pooled
mix is checked against a count by hand; the figure stays one size however many objects there are."""

from __future__ import annotations

import numpy as np
from PIL import Image

from graspgen.io.dataset_table import OUTCOME_NAMES
from graspgen.viz import plots


def _stats(outcomes_by_object: dict[str, list[int]]) -> dict:
    total = np.sum(list(outcomes_by_object.values()), axis=0)
    return {
        "outcomes": [{"name": n, "grasps": int(c)} for n, c in zip(OUTCOME_NAMES, total)],
        "counts": {"grasps": int(total.sum())},
        "objects": {o: {"grasps": int(sum(v)), "outcomes": [*v, 0]} for o, v in outcomes_by_object.items()},
    }


def test_few_objects_get_one_row_each_with_their_own_shares():
    stats = _stats({"mug": [1, 0, 0, 0, 1, 2], "box": [0, 0, 0, 0, 0, 3], "none": [0] * 6})
    rows, labels, _ = plots._outcome_rows(stats)
    assert labels == ["mug (4)", "box (3)"]  # an object without grasps has no row
    np.testing.assert_allclose(rows, [[0.25, 0, 0, 0, 0.25, 0.5], [0, 0, 0, 0, 0, 1]])


def test_many_objects_are_pooled_in_groups_sorted_by_success_share():
    n = 3 * plots.OUTCOME_ROWS
    # object i: i successes and n - i slips, so sorted by success share the order is n-1, n-2, ..., 0
    stats = _stats({f"o{i:03d}": [0, 0, 0, 0, n - i, i] for i in range(n)})
    rows, labels, title = plots._outcome_rows(stats)
    assert len(rows) == plots.OUTCOME_ROWS and labels[0] == "objects 1-3" and labels[-1] == f"objects {n - 2}-{n}"
    first = [n - 1, n - 2, n - 3]  # the three most successful objects, pooled
    np.testing.assert_allclose(rows[0][5], sum(first) / (3 * n))
    np.testing.assert_allclose(rows.sum(axis=1), 1.0)
    assert f"{n} objects" in title


def test_the_figure_is_one_size_past_the_row_limit(tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sizes = []
    for n in (plots.OUTCOME_ROWS + 1, 10 * plots.OUTCOME_ROWS):
        stats = _stats({f"o{i:04d}": [i % 2, 0, 0, 1, 0, 2] for i in range(n)})
        root = tmp_path / str(n)
        plots._outcomes_plot(plt, root, stats)
        with Image.open(root / "plots" / "outcomes.png") as image:
            sizes.append(image.size)
    assert sizes[0] == sizes[1]


def test_the_scatter_draws_the_rows_with_the_smallest_hashes_past_its_limit(tmp_path, monkeypatch):
    """Past SCATTER_POINTS the correlation scatter draws the rows whose (scene_id, grasp_id) hashes are smallest
    (a full sort is the truth), in table order; below it, every pair."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import pyarrow as pa

    from graspgen.io.card_labels import row_hash

    rng = np.random.default_rng(0)
    n = 400
    sid = [f"s{i // 50}" for i in range(n)]
    r = np.where(rng.random(n) < 0.7, rng.integers(0, 6, n) / 5, np.nan)
    table = pa.table({"scene_id": sid, "grasp_id": np.arange(n) % 50, "robustness": r, "epsilon": rng.random(n)})
    ok = np.isfinite(r)
    stats = {"correlation": {"columns": ["robustness", "epsilon"], "n": [[0, int(ok.sum())], [int(ok.sum()), 0]],
                             "spearman": [[1.0, 0.1], [0.1, 1.0]]}}
    drawn = {}

    def scatter(self, x, y, **kwargs):
        drawn["x"] = np.asarray(x)
        return real(self, x, y, **kwargs)

    real = matplotlib.axes.Axes.scatter
    monkeypatch.setattr(matplotlib.axes.Axes, "scatter", scatter)
    monkeypatch.setattr(plots, "SCATTER_POINTS", 40)
    (tmp_path / "plots").mkdir()
    assert plots._correlation_plot(plt, tmp_path, table, stats) == "plots/correlation.png"
    h = row_hash(table.column("scene_id"), table.column("grasp_id").to_numpy())
    rows = np.flatnonzero(ok)[np.argsort(h[ok])[:40]]
    assert np.array_equal(drawn["x"], table.column("epsilon").to_numpy()[np.sort(rows)])
    monkeypatch.setattr(plots, "SCATTER_POINTS", 10_000)
    plots._correlation_plot(plt, tmp_path, table, stats)
    assert np.array_equal(drawn["x"], table.column("epsilon").to_numpy()[ok])
