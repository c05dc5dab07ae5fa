"""The sweep report: the claims' point-and-interval rows, the per-evaluation-set interval panels and the plateau table."""

import numpy as np
import pandas as pd
import pytest

from sb3_latentswarm.experiments.report import CELL_COLUMNS, _interval_panels, plot_cells, plot_intervals


def aggregate() -> pd.DataFrame:
    rows = []
    cells = [("table1", c, 0.3) for c in ("proposed", "no_comm")] + [(f"p_fail={p}", "proposed", p) for p in (0.0, 0.5)]
    for k, (eval_set, condition, p_fail) in enumerate(cells):
        for j, variant in enumerate(("proposed", "no_comm")):
            value = 90.0 - 10 * j - k
            rows.append(dict(eval_set=eval_set, condition=condition, p_fail=p_fail, variant=variant, metric="coverage",
                             n_runs=3, iqm=value, iqm_low=value - 1, iqm_high=value + 1, mean=value, mean_low=value - 2,
                             mean_high=value + 2))
    return pd.DataFrame(rows)


def test_one_cell_sets_share_a_panel():
    panels = _interval_panels(aggregate(), list(CELL_COLUMNS))
    assert [title for title, _ in panels] == ["table1", "one-cell evaluation sets"]
    assert [label for label, _ in panels[1][1]] == ["p_fail=0.0: proposed 0.0", "p_fail=0.5: proposed 0.5"]


def test_figures_are_written_at_a_legible_size(tmp_path):
    from PIL import Image

    assert plot_intervals(aggregate(), [*CELL_COLUMNS, "variant"], tmp_path) == ["intervals_coverage.png"]
    cells = [("with links", {"eval_set": "table1", "condition": "proposed", "variant": "proposed"}),
             ("without", {"eval_set": "table1", "condition": "no_comm", "variant": "no_comm"})]
    path = plot_cells(aggregate(), cells, tmp_path / "claim.png", reference=(85.0, "target"))
    for image in (tmp_path / "intervals_coverage.png", path):
        width, height = Image.open(image).size
        assert width <= 1600 and width <= 3.5 * height


def test_a_cell_must_select_exactly_one_row(tmp_path):
    with pytest.raises(ValueError, match="selects 2 rows of coverage, expected 1"):
        plot_cells(aggregate(), [("both", {"eval_set": "table1", "condition": "proposed"})], tmp_path / "x.png")
    with pytest.raises(ValueError, match="selects 0 rows"):
        plot_cells(aggregate(), [("none", {"eval_set": "burst30"})], tmp_path / "x.png")


def test_training_plateau_slope_tells_a_rising_curve_from_a_flat_one():
    from sb3_latentswarm.experiments.report import training_plateau

    steps = np.arange(1, 31) * 100_000.0  # 30 reports, 3M agent-steps
    rows = []
    for seed in range(2):
        rows += [dict(agent_steps=s, coverage=50 + 10 * s / 1e6 + seed, trial_id=f"rising-seed{seed}", variant="rising",
                      train_seed=seed) for s in steps]  # +10 points per 1M agent-steps
        rows += [dict(agent_steps=s, coverage=90.0 + seed, trial_id=f"flat-seed{seed}", variant="flat", train_seed=seed)
                 for s in steps]
    plateau = training_plateau(pd.DataFrame(rows), []).set_index("variant")
    assert plateau.loc["rising", "slope_per_M"] == pytest.approx(10.0)
    assert plateau.loc["flat", "slope_per_M"] == pytest.approx(0.0, abs=1e-9)
    assert plateau.loc["flat", "final_coverage"] == pytest.approx(90.5)  # across-seed mean of the last third
    assert (plateau.loc["flat", "final_coverage_min"], plateau.loc["flat", "final_coverage_max"]) == (90.0, 91.0)
    assert (plateau["seeds"] == 2).all()
    # the last third of the rising curve: reports 21..30, mean coverage 50 + 10 * 2.55 (+ 0.5 across seeds)
    assert plateau.loc["rising", "final_coverage"] == pytest.approx(76.0)
    with pytest.raises(ValueError, match="fraction must be in"):
        training_plateau(pd.DataFrame(rows), [], fraction=0.0)
