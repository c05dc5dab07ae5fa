"""Training callbacks that count in swarms and agent-steps.

SB3's ``learn`` collects whole rollouts of ``n_steps * n_envs`` agent-steps while ``num_timesteps`` is below the
budget, so a run ends past a budget that is not a multiple of a rollout; SB3's progress bar then ends past 100 %
(2,880/2,000). :class:`RolloutProgressBarCallback` is SB3's bar with the total the run reaches.

SB3's ``EvalCallback`` on a swarm VecEnv counts each swarm episode once per agent (every slot reports the end of the
shared episode) and its ``eval_freq`` counts calls of ``on_step``, i.e. vec-env steps of ``n_envs * n_agents``
agent-steps. :class:`SwarmEvalCallback` evaluates whole swarm episodes with :func:`~sb3_latentswarm.evaluation.evaluate`
and counts its frequency in agent-steps, SB3's ``num_timesteps``.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path
from typing import Any

from stable_baselines3.common.callbacks import BaseCallback, ProgressBarCallback
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm

from sb3_latentswarm.config import SwarmConfig
from sb3_latentswarm.evaluation import HELD_OUT_SEED, check_condition, evaluate
from sb3_latentswarm.utils.checks import check_bool, check_float, check_int


def whole_rollouts(timesteps: int, per_rollout: int) -> int:
    """The agent-steps ``learn(timesteps)`` runs: ``timesteps`` rounded up to whole rollouts.

    :param timesteps: the budget passed to ``learn``, agent-steps (>= 1)
    :param per_rollout: agent-steps per rollout, ``n_steps * env.num_envs`` (each vec-env slot is one agent)
    :raise ValueError: for a value below 1
    """
    timesteps, per_rollout = check_int("timesteps", timesteps, low=1), check_int("per_rollout", per_rollout, low=1)
    return -(-timesteps // per_rollout) * per_rollout


class RolloutProgressBarCallback(ProgressBarCallback):
    """SB3's ``ProgressBarCallback`` (tqdm + rich) whose total is the agent-steps an on-policy run reaches, so the bar
    ends at 100 %: :func:`whole_rollouts` of the steps still to run. Pass it as ``callback`` instead of
    ``progress_bar=True``.

    ``sb3-latentswarm train`` shows it on a terminal.
    """

    def _on_training_start(self) -> None:
        from tqdm import TqdmExperimentalWarning
        from tqdm.rich import tqdm  # SB3's bar

        remaining = self.locals["total_timesteps"] - self.model.num_timesteps
        if isinstance(self.model, OnPolicyAlgorithm) and remaining > 0:  # off-policy runs keep SB3's total
            remaining = whole_rollouts(remaining, self.model.n_steps * self.training_env.num_envs)
        with warnings.catch_warnings():  # as SB3 does: tqdm calls its rich bar experimental
            warnings.simplefilter("ignore", TqdmExperimentalWarning)
            self.pbar = tqdm(total=remaining)  # built anew: tqdm_rich.reset(total=...) raises TypeError in tqdm 4.70


def _check_folder(folder: Path) -> Path:
    """``folder``, unless it or one of its parents is an existing file (then ``best_model.zip`` could never be saved)."""
    for candidate in (folder, *folder.parents):
        if candidate.exists():
            if not candidate.is_dir():
                what = "is" if candidate == folder else f"is inside {candidate}, which is"
                raise ValueError(f"best_model_save_path {folder} {what} an existing file, not a folder")
            break
    return folder


class SwarmEvalCallback(BaseCallback):
    """Evaluate the swarm every ``eval_freq`` agent-steps and log coverage, collisions and steps to 90 % under ``eval/``.

    The evaluation runs at the end of the first rollout at or past each multiple of ``eval_freq`` (so between updates,
    never inside a rollout: it evaluates the policy that collected that rollout), on its own env copies: training's
    envs and carried latent state are not touched. Each swarm episode counts once. Logged keys (means over the
    ``n_eval_episodes`` swarm episodes): ``eval/coverage`` (final coverage, %), ``eval/coverage_std``,
    ``eval/collisions``, ``eval/steps_to_90`` (over the episodes that reached 90 %; NaN when none did),
    ``eval/reached_90`` (fraction of episodes that reached 90 %), ``eval/episode_return``.

    :param eval_freq: agent-steps between evaluations (SB3's ``num_timesteps``; one update is ``n_steps * n_envs *
        n_agents`` of them)
    :param n_eval_episodes: swarm episodes per evaluation
    :param config: env config of the evaluation (default: the training env's, ``model.swarm_config``)
    :param condition: a name of :data:`~sb3_latentswarm.evaluation.CONDITION_TABLE`
    :param p_fail: link failure probability (default: the config's)
    :param deterministic: act with the policy's mean action (``False``: sample it)
    :param seed: episode ``k`` of every evaluation uses env seed ``seed + k`` (the same maps each time); default
        :data:`~sb3_latentswarm.evaluation.HELD_OUT_SEED`, disjoint from the training env seeds
    :param best_model_save_path: if given, the model is saved there as ``best_model.zip`` whenever the mean coverage
        improves
    :param verbose: 1 prints one line per evaluation
    :raise TypeError, ValueError: at construction, for a bad argument (``n_eval_episodes`` and ``eval_freq`` >= 1,
        ``p_fail`` in [0, 1], ``seed`` >= 0, a ``best_model_save_path`` that is a file), before any training
    """

    def __init__(
        self,
        eval_freq: int,
        n_eval_episodes: int = 10,
        config: SwarmConfig | None = None,
        condition: str = "proposed",
        p_fail: float | None = None,
        deterministic: bool = True,
        seed: int = HELD_OUT_SEED,
        best_model_save_path: str | Path | None = None,
        verbose: int = 0,
    ):
        super().__init__(verbose)
        self.eval_freq = check_int("eval_freq (agent-steps)", eval_freq, low=1)
        self.n_eval_episodes = check_int("n_eval_episodes", n_eval_episodes, low=1)
        if config is not None and not isinstance(config, SwarmConfig):
            raise TypeError(f"config must be a SwarmConfig or None, got {type(config).__name__}")
        self.config = config
        check_condition(condition)
        self.condition = condition
        self.p_fail = None if p_fail is None else check_float("p_fail", p_fail, 0.0, 1.0)
        self.deterministic = check_bool("deterministic", deterministic)
        self.seed = check_int("seed", seed, low=0)
        check_int("verbose", verbose, low=0, high=2)
        self.best_model_save_path = None if best_model_save_path is None else _check_folder(Path(best_model_save_path))
        self.best_coverage = -math.inf
        self.evaluations: list[dict[str, Any]] = []
        """One dict per evaluation: ``num_timesteps`` and the logged means."""
        self._next_evaluation = self.eval_freq

    def _init_callback(self) -> None:
        self._next_evaluation = (self.num_timesteps // self.eval_freq + 1) * self.eval_freq

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        if self.num_timesteps < self._next_evaluation:
            return
        self._next_evaluation = (self.num_timesteps // self.eval_freq + 1) * self.eval_freq
        episodes = evaluate(
            self.model,
            self.condition,
            p_fail=self.p_fail,
            n_episodes=self.n_eval_episodes,
            seed=self.seed,
            config=self.config,
            deterministic=self.deterministic,
        )
        reached = episodes["steps_to_90"].notna()
        result = {
            "coverage": float(episodes["coverage"].mean()),
            "coverage_std": float(episodes["coverage"].std(ddof=0)),
            "collisions": float(episodes["collisions"].mean()),
            "steps_to_90": float(episodes.loc[reached, "steps_to_90"].mean()) if reached.any() else math.nan,
            "reached_90": float(reached.mean()),
            "episode_return": float(episodes["episode_return"].mean()),
        }
        for key, value in result.items():
            self.logger.record(f"eval/{key}", value)
        self.evaluations.append({"num_timesteps": self.num_timesteps, **result})
        if self.verbose >= 1:
            print(
                f"Eval at {self.num_timesteps:,} agent-steps: coverage {result['coverage']:.1f} %, collisions "
                f"{result['collisions']:.1f}, 90 % reached in {result['reached_90']:.0%} of {self.n_eval_episodes} episodes"
            )
        if self.best_model_save_path is not None and result["coverage"] > self.best_coverage:
            self.best_coverage = result["coverage"]
            self.best_model_save_path.mkdir(parents=True, exist_ok=True)
            self.model.save(self.best_model_save_path / "best_model.zip")
