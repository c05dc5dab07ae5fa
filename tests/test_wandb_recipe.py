"""docs/wandb.md's recipe (SB3's ``WandbCallback`` with ``sync_tensorboard=True``) runs as written, offline."""

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def recipe() -> str:
    (code,) = re.findall(r"```python\n(.*?)```", (ROOT / "docs" / "wandb.md").read_text(), re.S)
    return code


@pytest.mark.slow  # W&B's service starts and stops with the run: about 20 s for 300 agent-steps
def test_wandb_recipe_logs_the_tensorboard_scalars_and_the_model_offline(tmp_path):
    pytest.importorskip("wandb")
    code = recipe()
    # the documented run, shrunk: the smoke preset, two env copies, a few hundred agent-steps
    for documented, tiny in (('"demo"', '"smoke"'), ("make_vec_env(8,", "make_vec_env(2,"), ("learn(90_000,", "learn(300,")):
        assert documented in code, documented
        code = code.replace(documented, tiny)
    env = dict(os.environ, WANDB_MODE="offline", WANDB_DIR=str(tmp_path), WANDB_SILENT="true", PYTHONPATH=str(ROOT))
    result = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]
    (run_dir,) = (tmp_path / "wandb").glob("offline-run-*")
    run_id = run_dir.name.rsplit("-", 1)[-1]
    # the model WandbCallback saved loads as a LatentSwarmPPO, and went into the run's files
    from sb3_latentswarm import LatentSwarmPPO

    assert LatentSwarmPPO.load(tmp_path / "models" / run_id / "model.zip").num_timesteps >= 300
    assert (run_dir / "files" / "model.zip").exists()
    # sync_tensorboard: SB3's event file was copied into the run, and its scalars are in the run's record file (the
    # metric names are stored as plain protobuf strings there)
    assert list((run_dir / "files" / "runs" / run_id).rglob("events.out.tfevents.*"))
    (records,) = run_dir.glob("run-*.wandb")
    data = records.read_bytes()
    for key in (b"train/loss", b"train/pred_loss", b"rollout/coverage", b"rollout/dropout_rate"):
        assert key in data, key
