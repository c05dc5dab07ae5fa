"""examples/paired_comparison.py: paired across-seed differences and the threshold verdict, on hand-built scores."""

from __future__ import annotations

import runpy
from pathlib import Path

import pandas as pd
import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "examples" / "paired_comparison.py"


def _scores(tmp_path: Path) -> Path:
    rows = []
    # proposed leads zero_substitute by 4, 5, 6 points (seeds 0-2); hold_last is ahead of proposed by 1 on each seed
    for seed, (p, z, h) in enumerate([(90.0, 86.0, 91.0), (92.0, 87.0, 93.0), (94.0, 88.0, 95.0)]):
        for variant, value in (("proposed", p), ("zero_substitute", z), ("hold_last", h)):
            rows.append({"eval_set": "table1", "condition": "proposed", "variant": variant, "train_seed": seed,
                         "coverage": value})
            rows.append({"eval_set": "table1", "condition": "no_comm", "variant": variant, "train_seed": seed,
                         "coverage": 0.0})
    rows.append({"eval_set": "pf1", "condition": "proposed", "variant": "proposed", "train_seed": 0, "coverage": 50.0})
    path = tmp_path / "scores.csv"
    pd.DataFrame(rows).to_csv(path, index=False)
    return path


def test_paired_differences_and_verdicts(tmp_path, capsys):
    module = runpy.run_path(str(SCRIPT))
    output = tmp_path / "paired.md"
    module["main"](["--scores", str(_scores(tmp_path)), "--against", "zero_substitute", "hold_last",
                    "--cells", "table1", "pf1", "--threshold", "3", "--output", str(output)])
    lines = capsys.readouterr().out.splitlines()
    assert output.read_text().splitlines() == lines
    rows = {tuple(cell.strip() for cell in line.strip("|").split("|")[:2]): line for line in lines[2:]}
    # mean of (4, 5, 6) is 5; every bootstrap replicate lies in [4, 6], so the interval is inside it and above 0
    zero = rows[("zero_substitute", "table1")]
    assert "| 3 (0,1,2) | 92.00 | 87.00 | +5.00 [+4." in zero and zero.endswith("| met |")
    assert rows[("hold_last", "table1")].endswith("| not met |") and "-1.00 [-1.00, -1.00]" in rows[("hold_last", "table1")]
    # pf1 has no finished pair for either learner
    assert rows[("zero_substitute", "pf1")].endswith("| not tested |")


def test_fewer_seeds_than_the_minimum_give_no_verdict(tmp_path, capsys):
    module = runpy.run_path(str(SCRIPT))
    module["main"](["--scores", str(_scores(tmp_path)), "--against", "zero_substitute", "--cells", "table1",
                    "--min-seeds", "4"])
    row = capsys.readouterr().out.splitlines()[2]
    assert "+5.00" in row and row.endswith("| no verdict (< 4 seeds) |")


def test_a_learner_swept_apart_is_read_at_its_own_condition(tmp_path, capsys):
    module = runpy.run_path(str(SCRIPT))
    apart = tmp_path / "apart"
    apart.mkdir()
    rows = []  # the learner trained without links: 80, 81, 82 in its own condition, nonsense (0) with links up
    for seed, value in enumerate((80.0, 81.0, 82.0)):
        for condition, score in (("no_comm", value), ("proposed", 0.0)):
            rows.append({"eval_set": "table1", "condition": condition, "variant": "no_comm", "train_seed": seed,
                         "coverage": score})
    pd.DataFrame(rows).to_csv(apart / "scores.csv", index=False)
    module["main"](["--scores", str(_scores(tmp_path)), str(apart / "scores.csv"), "--against", "no_comm",
                    "--against-condition", "no_comm", "--cells", "table1", "--threshold", "10"])
    row = capsys.readouterr().out.splitlines()[2]
    # proposed 90, 92, 94 (condition proposed) against 80, 81, 82 (condition no_comm): +11 on average
    assert "| 3 (0,1,2) | 92.00 | 81.00 | +11.00 [+10." in row and row.endswith("| met |")
    # without --against-condition both are read at `proposed`: the no_comm learner's 0s
    module["main"](["--scores", str(_scores(tmp_path)), str(apart / "scores.csv"), "--against", "no_comm",
                    "--cells", "table1", "--threshold", "10"])
    assert "| 92.00 | 0.00 | +92.00" in capsys.readouterr().out


def test_a_learner_compared_with_itself_at_another_condition(tmp_path, capsys):
    module = runpy.run_path(str(SCRIPT))
    module["main"](["--scores", str(_scores(tmp_path)), "--against", "proposed", "--against-condition", "no_comm",
                    "--cells", "table1", "--threshold", "3"])
    row = capsys.readouterr().out.splitlines()[2]  # proposed with links (90, 92, 94) against itself without (0s)
    assert "| 3 (0,1,2) | 92.00 | 0.00 | +92.00" in row and row.endswith("| met |")


def test_bad_scores_and_names_stop_with_one_clear_line(tmp_path):
    module = runpy.run_path(str(SCRIPT))
    scores = _scores(tmp_path)
    copy = tmp_path / "copy"
    copy.mkdir()
    (copy / "scores.csv").write_text(scores.read_text())  # the same trials twice: averaging them would hide it
    cases = [
        (["--scores", str(scores), str(copy / "scores.csv"), "--against", "hold_last", "--cells", "table1"],
         "comes more than once"),
        (["--scores", str(scores), "--against", "hold_lats", "--cells", "table1"], "no learner 'hold_lats'.*hold_last"),
        (["--scores", str(scores), "--against", "hold_last", "--cells", "tabel1"], "no cell 'tabel1'.*pf1, table1"),
        (["--scores", str(scores), "--against", "hold_last", "--cells", "table1", "--against-condition", "nocomm"],
         "no condition 'nocomm'"),
        (["--scores", str(scores), "--against", "hold_last", "--cells", "table1", "--metric", "return"],
         r"lacks the column\(s\) \['return'\]; it has eval_set, condition"),
    ]
    for argv, match in cases:
        with pytest.raises(SystemExit, match=match):
            module["main"](argv)
    with pytest.raises(SystemExit):  # argparse: exit status 2 and the message on stderr
        module["main"](["--scores", str(scores), "--against", "hold_last", "--cells", "table1", "--output",
                        str(tmp_path / "missing" / "paired.md")])
