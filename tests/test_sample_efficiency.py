"""examples/sample_efficiency.py: steps to target, normalized AUC and the paired differences on hand-made training curves."""

import gzip
import runpy
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "examples" / "sample_efficiency.py"
MODULE = runpy.run_path(str(SCRIPT))
STEPS = np.arange(100, 1001, 100, dtype=float)  # ten rollouts of 100 agent-steps


def write_trial(sweep: Path, variant: str, seed: int, steps: np.ndarray, coverage: np.ndarray, gzipped: bool = False):
    folder = sweep / "trials" / f"{variant}-seed{seed}"
    folder.mkdir(parents=True)
    frame = pd.DataFrame({
        "agent_steps": steps, "episode_reward": -1.0, "coverage": coverage, "collisions": 0.0,
        "trial_id": folder.name, "variant": variant, "train_seed": seed,
    })
    text = frame.to_csv(index=False)
    if gzipped:
        (folder / "progress.csv.gz").write_bytes(gzip.compress(text.encode()))
    else:
        (folder / "progress.csv").write_text(text)


@pytest.fixture
def sweep(tmp_path) -> Path:
    sweep = tmp_path / "sweep"
    write_trial(sweep, "proposed", 0, STEPS, STEPS / 10)  # a ramp 10 -> 100: mean level 55, 50 at 500, 90 at 900
    write_trial(sweep, "proposed", 1, STEPS, STEPS / 10 - 5)  # 5 -> 95: mean level 50, 50 at 600, 90 at 1000
    write_trial(sweep, "zero_substitute", 0, STEPS, STEPS / 20 - 1)  # 4 -> 49: mean 26.5; never 50
    write_trial(sweep, "zero_substitute", 1, STEPS, STEPS / 20 + 5)  # 10 -> 55: mean 32.5; 50 at 900, never 90
    # a longer run: 50 up to the common budget (1000 agent-steps), 100 after it; read only up to the budget
    longer = np.arange(100, 1201, 100, dtype=float)
    write_trial(sweep, "hold_last", 0, longer, np.where(longer <= 1000, 50.0, 100.0), gzipped=True)
    return sweep


def test_smoothing_steps_to_target_and_the_auc_of_a_ramp():
    smoothed, steps_to_target, normalized_auc = (MODULE[n] for n in ("smoothed", "steps_to_target", "normalized_auc"))
    np.testing.assert_allclose(smoothed(np.array([10.0, 20.0, 30.0, 40.0]), 3), [10.0, 15.0, 20.0, 30.0])
    np.testing.assert_allclose(smoothed(np.array([10.0, 20.0]), 1), [10.0, 20.0])
    ramp = STEPS / 10
    assert steps_to_target(STEPS, ramp, 50.0) == 500.0 and steps_to_target(STEPS, ramp, 49.5) == 500.0
    assert np.isnan(steps_to_target(STEPS, ramp, 100.5))
    assert normalized_auc(STEPS, ramp, 100.0, 1000.0) == pytest.approx(55.0)  # a line's mean: its midpoint
    assert normalized_auc(STEPS, ramp, 150.0, 450.0) == pytest.approx(30.0)  # between rollouts: interpolated
    with pytest.raises(ValueError, match="must lie inside"):
        normalized_auc(STEPS, ramp, 100.0, 1100.0)


def test_per_trial_table_is_cut_at_the_common_budget_and_the_paired_sign_is_reference_minus_other(sweep, tmp_path, capsys):
    output = tmp_path / "out"
    MODULE["main"](["--sweep", str(sweep), "--targets", "90", "50", "--window", "1", "--output", str(output),
                    "--against", "zero_substitute", "hold_last"])
    table = pd.read_csv(output / "per_trial.csv").set_index("trial_id")
    assert list(table.columns[-2:]) == ["steps_to_50", "steps_to_90"]
    np.testing.assert_allclose(table["auc"], [50.0, 55.0, 50.0, 26.5, 32.5])  # hold_last, proposed x2, zero x2
    assert table.loc["hold_last-seed0", "final_agent_steps"] == 1200  # its own end, but scored up to 1000 only
    assert np.isnan(table.loc["hold_last-seed0", "steps_to_90"])  # it reaches 100 at 1100: beyond the budget
    assert table.loc["hold_last-seed0", "level_at_budget"] == 50.0
    assert table.loc["proposed-seed1", "steps_to_50"] == 600 and table.loc["proposed-seed1", "steps_to_90"] == 1000
    assert np.isnan(table.loc["zero_substitute-seed0", "steps_to_50"])
    assert table.loc["zero_substitute-seed1", "steps_to_50"] == 900

    markdown = (output / "sample_efficiency.md").read_text()
    assert markdown == capsys.readouterr().out
    assert "common budget 1,000 agent-steps" in markdown and "TRAINING curves" in markdown and "targets 50, 90" in markdown
    assert "| `proposed` | 2 | 52.50 [50.00, 55.00] |" in markdown
    assert "| 550 [500, 600] (all 2) |" in markdown  # proposed's mean steps to 50
    assert "| `zero_substitute` | 2 | 29.50 [26.50, 32.50] |" in markdown
    assert "| 1 of 2 seeds reached it | 0 of 2 seeds reached it |" in markdown
    # proposed minus zero_substitute: +28.5 and +17.5 points; steps to 50 over the one seed where both got there
    assert "| `zero_substitute` | AUC (points) | 2 (0,1) | 52.50 | 29.50 | +23.00 [+17.50, +28.50] (< 3 pairs" in markdown
    assert "| `zero_substitute` | steps to 50 | 1 (1) | 600 | 900 | -300 (< 3 pairs: the interval says little) |" in markdown
    assert "| `zero_substitute` | steps to 90 | 0 | | | no seed where both reached it |" in markdown
    assert "| `hold_last` | AUC (points) | 1 (0) | 55.00 | 50.00 | +5.00 (< 3 pairs" in markdown


def test_a_longer_window_delays_the_target(sweep, tmp_path):
    MODULE["main"](["--sweep", str(sweep), "--targets", "50", "--window", "3", "--output", str(tmp_path / "w3")])
    table = pd.read_csv(tmp_path / "w3" / "per_trial.csv").set_index("trial_id")
    assert table.loc["proposed-seed0", "steps_to_50"] == 600  # the mean of the last three: s/10 - 10


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--window", "0"], "--window must be >= 1, got 0"),
        (["--against", "zero_subst"], "unknown variant(s) zero_subst; the sweep holds: hold_last, proposed, zero_substitute"),
        (["--reference", "predictor"], "unknown variant(s) predictor; the sweep holds:"),
        (["--against", "proposed"], "--against must name other learners than --reference"),
        (["--metric", "reward"], "lacks the column(s) ['reward']"),
        (["--targets"], "--targets: expected at least one argument"),
    ],
)
def test_bad_arguments_stop_before_any_work(sweep, tmp_path, capsys, extra, message):
    argv = ["--sweep", str(sweep), "--output", str(tmp_path / "out"), "--targets", "50", *extra]
    with pytest.raises(SystemExit) as exit_info:
        MODULE["main"](argv)
    assert exit_info.value.code == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_a_folder_without_trials_is_refused(tmp_path, capsys):
    with pytest.raises(SystemExit):
        MODULE["main"](["--sweep", str(tmp_path), "--output", str(tmp_path / "out"), "--targets", "50"])
    assert "has no trials/ folder" in capsys.readouterr().err
