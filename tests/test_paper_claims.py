"""examples/paper_claims.py on synthetic sweep scores with known verdicts."""

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
spec = importlib.util.spec_from_file_location("paper_claims", ROOT / "examples" / "paper_claims.py")
paper_claims = importlib.util.module_from_spec(spec)
spec.loader.exec_module(paper_claims)


def synthetic_scores(proposed=90.0, no_comm=75.0, full_comm=91.0, no_predictor=80.0, collisions=5.0) -> pd.DataFrame:
    rows = []
    for seed in range(3):
        jitter = seed - 1.0  # -1, 0, 1: a narrow interval around each mean

        def add(variant, eval_set, condition, coverage, steps=40.0, seed=seed, jitter=jitter):
            rows.append(dict(variant=variant, train_seed=seed, trial_id=f"{variant}-seed{seed}", eval_set=eval_set,
                             condition=condition, p_fail=0.3, coverage=coverage + jitter, collisions=collisions,
                             steps_to_90=steps, reached_90=50.0))

        add("proposed", "table1", "proposed", proposed)
        add("proposed", "table1", "full_comm", full_comm)
        add("proposed", "table1", "no_predictor", no_predictor)
        add("proposed", "table1", "no_memory", proposed - 1.0)
        add("no_comm", "table1", "no_comm", no_comm)
        add("independent", "table1", "proposed", no_comm - 5.0)
        for p, offset in (("p_fail=0", 0.0), ("p_fail=0.5", -2.0)):
            add("proposed", p, "proposed", proposed + offset)
    return pd.DataFrame(rows)


def verdicts(rows):
    return {row["claim"]: row["met"] for row in rows}


def test_claims_on_known_scores():
    rows = paper_claims.check_claims(synthetic_scores(), "table1", {"table1": 10}, ["p_fail=0", "p_fail=0.5"])
    got = verdicts(rows)
    assert got["1. Proposed vs best message-free learner"] == "yes"  # 15 points, disjoint intervals
    assert got["2. full_comm vs Proposed"] == "yes"
    assert got["3. mean outage 10 steps: Proposed vs no_predictor"] == "yes"  # 10 points
    assert got["3. mean outage 10 steps: Proposed vs no_memory"] == "no"  # 1 point
    assert got["4. coverage across p_f"] == "yes"  # spread 2
    assert got["5. collisions per episode (Proposed)"] == "yes"
    assert "no_comm" in rows[0]["measured"]  # the stronger message-free learner is named


def test_claim_3_compares_the_learners_trained_with_another_substitute():
    scores = synthetic_scores(proposed=90.0)
    extra = scores[(scores["variant"] == "proposed") & (scores["condition"] == "proposed")
                   & (scores["eval_set"] == "table1")]
    trained = [extra.assign(variant=variant, trial_id=extra["trial_id"].str.replace("proposed", variant),
                            coverage=extra["coverage"] - gap)
               for variant, gap in (("zero_substitute", 7.0), ("hold_last", 2.0))]
    got = verdicts(paper_claims.check_claims(pd.concat([scores, *trained]), "table1", {"table1": 10}, []))
    assert got["3. mean outage 10 steps: Proposed vs trained zero_substitute"] == "yes"  # 7 points
    assert got["3. mean outage 10 steps: Proposed vs trained hold_last"] == "no"  # 2 points
    assert "3. mean outage 10 steps: Proposed vs trained hold_last" not in verdicts(  # absent learners: no row
        paper_claims.check_claims(scores, "table1", {"table1": 10}, []))


def test_claims_that_fail_are_reported_as_failed():
    scores = synthetic_scores(proposed=80.0, no_comm=75.0, full_comm=70.0, collisions=20.0)
    got = verdicts(paper_claims.check_claims(scores, "table1", {}, ["p_fail=0", "p_fail=0.5"]))
    assert got["1. Proposed vs best message-free learner"] == "no"  # 5 points only
    assert got["2. full_comm vs Proposed"] == "no"
    assert got["5. collisions per episode (Proposed)"] == "no"


def test_script_writes_claims_beside_the_sweep(tmp_path):
    synthetic_scores().to_csv(tmp_path / "scores.csv", index=False)  # the sweep's own scores: mean actions
    # sampled-action scores measured earlier by the script (it would evaluate the sweep's models otherwise)
    synthetic_scores(proposed=95.0, collisions=20.0).to_csv(tmp_path / "scores_sampled.csv", index=False)
    eval_sets = [{"name": "table1", "overrides": {}, "conditions": None},
                 {"name": "p_fail=0", "overrides": {"p_fail": 0.0}, "conditions": ["proposed"]},
                 {"name": "p_fail=0.5", "overrides": {"p_fail": 0.5}, "conditions": ["proposed"]}]
    spec = {"preset": "smoke", "overrides": {}, "eval_sets": eval_sets, "eval_seed": 1_000_000, "eval_episodes": 10,
            "deterministic": True}
    (tmp_path / "sweep.json").write_text(json.dumps(spec))
    result = subprocess.run(
        [sys.executable, "examples/paper_claims.py", "--sweep", str(tmp_path), "--burst-cells", "table1=10"],
        cwd=ROOT, capture_output=True, text=True, timeout=120,
    )
    assert result.returncode == 0, result.stderr
    claims = pd.read_csv(tmp_path / "claims.csv")
    assert claims["actions"].drop_duplicates().tolist() == ["sampled", "mean"]  # the paper's protocol first
    mean = claims[claims["actions"] == "mean"]
    assert len(mean) == 6 and set(mean["met"]) == {"yes", "no"}  # no full_comm_in_range cell here
    sampled = claims[claims["actions"] == "sampled"].set_index("claim")["met"]
    assert sampled["5. collisions per episode (Proposed)"] == "no"  # read from scores_sampled.csv: 20 collisions
    text = (tmp_path / "claims.md").read_text()
    assert "spread 2.00" in text and text.index("## Sampled actions") < text.index("## Mean actions")
    assert "episode seeds 1000000-1000009" in text


def test_a_second_call_measures_only_the_trials_finished_since(tmp_path, monkeypatch, capsys):
    scores = synthetic_scores()
    scores.to_csv(tmp_path / "scores.csv", index=False)
    eval_sets = [{"name": "table1", "overrides": {}, "conditions": None}]
    spec = {"preset": "smoke", "overrides": {}, "eval_sets": eval_sets, "eval_seed": 1_000_000, "eval_episodes": 10,
            "deterministic": True}
    (tmp_path / "sweep.json").write_text(json.dumps(spec))
    measured = []

    def fake_evaluate_sweep(sweep, spec, mode, skip=()):
        todo = [p.name for p in paper_claims.finished_trial_dirs(sweep) if p.name not in skip]
        measured.append(todo)
        return scores[scores["trial_id"].isin(todo)]

    monkeypatch.setattr(paper_claims, "evaluate_sweep", fake_evaluate_sweep)
    for trial_id in ("proposed-seed0", "no_comm-seed0"):
        (tmp_path / "trials" / trial_id).mkdir(parents=True)
        (tmp_path / "trials" / trial_id / "trial.json").write_text("{}")
    paper_claims.main(["--sweep", str(tmp_path), "--actions", "sampled"])
    (tmp_path / "trials" / "proposed-seed1").mkdir()
    (tmp_path / "trials" / "proposed-seed1" / "trial.json").write_text("{}")
    paper_claims.main(["--sweep", str(tmp_path), "--actions", "sampled"])
    paper_claims.main(["--sweep", str(tmp_path), "--actions", "sampled"])  # nothing new: nothing measured
    assert measured == [["no_comm-seed0", "proposed-seed0"], ["proposed-seed1"]]
    kept = pd.read_csv(tmp_path / "scores_sampled.csv")
    assert sorted(kept["trial_id"].unique()) == ["no_comm-seed0", "proposed-seed0", "proposed-seed1"]


def test_with_sweep_joins_another_sweeps_learners_on_the_same_cells(tmp_path, capsys):
    import pytest

    scores = synthetic_scores(no_comm=70.0)
    main_dir, other_dir = tmp_path / "main", tmp_path / "independent"
    eval_sets = [{"name": "table1", "overrides": {}, "conditions": None}]
    spec = {"preset": "smoke", "overrides": {}, "eval_sets": eval_sets, "eval_seed": 1_000_000, "eval_episodes": 10,
            "deterministic": False}
    for folder, part in ((main_dir, scores[scores["variant"] != "independent"]),
                         (other_dir, synthetic_scores(no_comm=80.0).query("variant == 'independent'"))):
        folder.mkdir()
        part.to_csv(folder / "scores.csv", index=False)
        (folder / "sweep.json").write_text(json.dumps(spec))
    paper_claims.main(["--sweep", str(main_dir), "--with-sweep", str(other_dir), "--actions", "sampled"])
    claim_1 = pd.read_csv(main_dir / "claims.csv").iloc[0]
    # the independent learner of the other sweep (75 %) is the best message-free learner, above no_comm's 70 %
    assert claim_1["measured"].startswith("Proposed 90.00") and "vs independent 75.00" in claim_1["measured"]
    assert f"with `{other_dir}`" in (main_dir / "claims.md").read_text()
    (other_dir / "sweep.json").write_text(json.dumps({**spec, "eval_episodes": 5}))
    with pytest.raises(SystemExit):
        paper_claims.main(["--sweep", str(main_dir), "--with-sweep", str(other_dir), "--actions", "sampled"])
    assert "its eval_episodes differ from --sweep's" in capsys.readouterr().err


def test_claims_on_another_metric_scale_the_papers_points_to_its_range():
    # simple_spread-like returns: the paper's coverage points become percentages of the stated range (8.6 points)
    scores = synthetic_scores(proposed=-25.0, no_comm=-26.5, full_comm=-25.1, no_predictor=-25.5, collisions=4.0)
    scores = scores.rename(columns={"coverage": "return", "collisions": "sum_collisions"})
    scores["return"] = scores["return"] - scores["train_seed"] + 1.0 + 0.01 * (scores["train_seed"] - 1)  # narrow CIs
    scale = paper_claims.Scale("return", -34.4, -25.8)
    rows = paper_claims.check_claims(scores, "table1", {"table1": 5}, ["p_fail=0", "p_fail=0.5"], scale)
    got = verdicts(rows)
    assert got["1. Proposed vs best message-free learner"] == "yes"  # +1.5 >= 0.86, disjoint
    assert got["2. full_comm vs Proposed"] == "yes"  # -0.1 >= -0.129
    assert got["3. mean outage 5 steps: Proposed vs no_predictor"] == "yes"  # +0.5 >= 0.43
    assert got["3. mean outage 5 steps: Proposed vs no_memory"] == "yes"  # +1.0
    assert got["4. return across p_f"] == "no"  # spread 2 > 0.258
    assert got["5. collisions per episode (Proposed)"] == "n/a"  # the paper's 8.7 is of its own task
    targets = {row["claim"]: row["target"] for row in rows}
    assert targets["1. Proposed vs best message-free learner"] == ">= 10 % of the range (0.86), disjoint 95 % CIs"
    assert "sum_collisions" in rows[-1]["measured"]
    near = scores.assign(**{"return": scores["return"].where(scores["condition"] != "no_predictor", -25.4)})
    got = verdicts(paper_claims.check_claims(near, "table1", {"table1": 5}, [], scale))
    assert got["3. mean outage 5 steps: Proposed vs no_predictor"] == "no"  # +0.4 < 0.43


def test_another_metric_needs_its_range(tmp_path):
    synthetic_scores().rename(columns={"coverage": "return"}).to_csv(tmp_path / "scores.csv", index=False)
    (tmp_path / "sweep.json").write_text(json.dumps({"preset": "smoke", "overrides": {}, "eval_sets": []}))
    for extra, message in ((["--metric", "return"], "--metric-range"),
                           (["--metric", "return", "--metric-range", "1", "1"], "LOW < HIGH"),
                           (["--metric", "landmarks", "--metric-range", "0", "1"], "not a column")):
        result = subprocess.run([sys.executable, "examples/paper_claims.py", "--sweep", str(tmp_path), *extra],
                                cwd=ROOT, capture_output=True, text=True, timeout=120)
        assert result.returncode == 2 and message in result.stderr, result.stderr


def test_claim_1_without_a_message_free_learner_is_not_applicable():
    scores = synthetic_scores().query("variant == 'proposed'")
    rows = paper_claims.check_claims(scores, "table1", {}, [])
    assert verdicts(rows)["1. Proposed vs best message-free learner"] == "n/a"
    assert "no message-free learner" in rows[0]["measured"]


def test_cells_and_ranges_are_checked_before_the_claims(tmp_path):
    scores = synthetic_scores().rename(columns={"coverage": "return"})
    scores.to_csv(tmp_path / "scores.csv", index=False)
    spec = {"preset": "smoke", "overrides": {}, "eval_sets": [], "deterministic": False}
    (tmp_path / "sweep.json").write_text(json.dumps(spec))

    def run(*extra):
        return subprocess.run([sys.executable, "examples/paper_claims.py", "--sweep", str(tmp_path), *extra],
                              cwd=ROOT, capture_output=True, text=True, timeout=120)

    for extra, message in (([], "--metric return --metric-range"),  # an adapted env's sweep has no coverage
                           (["--metric", "return", "--metric-range", "0", "100", "--burst-cells", "table1"],
                            "CELL=MEAN_OUTAGE_STEPS"),
                           (["--metric", "return", "--metric-range", "0", "100", "--base-cell", "nope"], "unknown cell"),
                           (["--metric", "return", "--metric-range", "0", "100", "--burst-cells", "foo=5"], "foo")):
        result = run(*extra)
        assert result.returncode == 2 and message in result.stderr, (extra, result.stderr)
    result = run("--metric", "return", "--metric-range", "0", "50", "--actions", "sampled")  # scores reach 91
    assert result.returncode == 0, result.stderr
    assert "lie outside the stated range 0 to 50" in (tmp_path / "claims.md").read_text()
    assert (tmp_path / "claim_1_message_free_learners.png").exists()  # no_comm beside proposed
    scores.query("variant == 'proposed'").to_csv(tmp_path / "scores.csv", index=False)
    (tmp_path / "claim_1_message_free_learners.png").unlink()
    assert run("--metric", "return", "--metric-range", "0", "100", "--actions", "sampled").returncode == 0
    assert not (tmp_path / "claim_1_message_free_learners.png").exists()  # claim 1 is n/a: no figure of it
    assert "lie outside" not in (tmp_path / "claims.md").read_text()
