"""Per-episode diagnostics of the message mechanism, accumulated over the agent-steps of every episode.

At every step t and agent i the runner records whether the agent acted in dropout (N_t^i empty: no live in-link,
Sec. III-C) and, for a latent-swarm policy, two errors:

* ``map_error``: the per-cell squared error of D(mu_t^i) against M_hat_t (the target of Eq. (3));
* the substitute error: at a dropout step, the per-element squared error between the message the policy used in
  place of the received one (mbar_t^i: mhat_t^i under ``proposed``, 0 under ``no_predictor``, the held or the own
  message under ``hold_last`` / ``own_message``) and the message full connectivity would have delivered, the mean
  of z_{t-1}^j over all peers j != i.

The *dropout depth* of a dropout step is its position in the agent's current run of consecutive dropout steps (1 at
the first step without a message, 2 at the next, ...; a step with a message ends the run, an episode start resets
it). Columns of one episode (all NaN where they do not apply: no dropout step, N = 1, or a model without a latent
policy for the error columns):

=============================  ===========================================================================
``map_error``                  mean of the map error over the agent-steps
``pred_error_dropout``         mean of the substitute error over the dropout agent-steps
``dropout_share``              share of the agent-steps (N x episode length) taken in dropout
``dropout_run_mean``           mean length of the agent's dropout runs, in steps (dropout steps / runs)
``pred_error_depth_1``         mean substitute error over the dropout steps at depth 1
``pred_error_depth_2_5``       ... at depth 2 to 5
``pred_error_depth_6_15``      ... at depth 6 to 15
``pred_error_depth_16_plus``   ... at depth 16 or more (more than 15 steps into the outage)
=============================  ===========================================================================
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["DEPTH_BINS", "DEPTH_COLUMNS", "DIAGNOSTIC_COLUMNS", "EPISODE_COLUMNS", "EpisodeDiagnostics"]

DEPTH_BINS = ((1, 1), (2, 5), (6, 15), (16, math.inf))
"""Dropout depths (first, last step, inclusive) of the ``pred_error_depth_*`` columns."""
DEPTH_COLUMNS = ("pred_error_depth_1", "pred_error_depth_2_5", "pred_error_depth_6_15", "pred_error_depth_16_plus")
"""Per-episode columns of the substitute error by dropout depth, one per :data:`DEPTH_BINS` entry."""
DIAGNOSTIC_COLUMNS = ("dropout_share", "dropout_run_mean", *DEPTH_COLUMNS)
"""The dropout diagnostics added to every per-episode row (after ``pred_error_dropout``)."""
EPISODE_COLUMNS = (
    "episode",
    "seed",
    "condition",
    "p_fail",
    "coverage",
    "collisions",
    "steps_to_90",
    "episode_return",
    "episode_length",
    "link_up_rate",
    "dropout_rate",
    "map_error",
    "pred_error_dropout",
    *DIAGNOSTIC_COLUMNS,
)
"""Columns of the per-episode DataFrame of :func:`~sb3_latentswarm.evaluation.evaluate`, in order: the episode, its
seed and cell, Table I's three metrics, the episode statistics of the env, then the diagnostics of this module."""
# bin of depth d (d >= 1): the number of bin starts <= d, minus one
_BIN_STARTS = np.array([low for low, _ in DEPTH_BINS])


class EpisodeDiagnostics:
    """Sums over the agent-steps of ``n_episodes`` episodes played in ``n_slots`` env-major agent slots.

    :param n_episodes: episodes of the evaluation (rows)
    :param n_slots: agent slots stepped together (swarms x agents)
    """

    def __init__(self, n_episodes: int, n_slots: int) -> None:
        self.n_episodes = n_episodes
        self.depth = np.zeros(n_slots, dtype=np.int64)  # current dropout depth of every slot (0: has a message)
        self.agent_steps = np.zeros(n_episodes)
        self.dropout_steps = np.zeros(n_episodes)
        self.dropout_runs = np.zeros(n_episodes)
        self.map_error_sum = np.zeros(n_episodes)
        self.map_error_count = np.zeros(n_episodes)
        self.pred_error_sum = np.zeros(n_episodes)
        self.pred_error_count = np.zeros(n_episodes)
        self.depth_sum = np.zeros((len(DEPTH_BINS), n_episodes))
        self.depth_count = np.zeros((len(DEPTH_BINS), n_episodes))

    def _add(self, target: np.ndarray, episodes: np.ndarray, weights: np.ndarray | None = None) -> None:
        # bincount adds each episode's entries in slot order, as a running sum per episode would
        target += np.bincount(episodes, weights=weights, minlength=self.n_episodes)

    def record(
        self,
        episode_of_slot: np.ndarray,
        episode_starts: np.ndarray,
        dropout: np.ndarray,
        map_error: np.ndarray | None = None,
        pred_error: np.ndarray | None = None,
    ) -> None:
        """Record one step of every slot.

        :param episode_of_slot: (n_slots,) the episode each slot plays, -1 for an idle slot (not recorded)
        :param episode_starts: (n_slots,) True where this step is the first of the slot's episode
        :param dropout: (n_slots,) True where the agent acted without a live in-link
        :param map_error: (n_slots,) the map error of the step, or ``None`` (no latent policy)
        :param pred_error: (n_slots,) the substitute error, NaN where the agent had a message, or ``None``
        """
        depth = np.where(episode_starts, 0, self.depth)
        self.depth = depth = np.where(dropout, depth + 1, 0)
        live = episode_of_slot >= 0
        episodes = episode_of_slot[live]
        live_dropout = dropout[live]
        self._add(self.agent_steps, episodes)
        self._add(self.dropout_steps, episodes[live_dropout])
        self._add(self.dropout_runs, episodes[live_dropout & (depth[live] == 1)])
        if map_error is not None:
            self._add(self.map_error_sum, episodes, map_error[live])
            self._add(self.map_error_count, episodes)
        if pred_error is not None:
            errors = pred_error[live]
            has_error = ~np.isnan(errors)
            self._add(self.pred_error_sum, episodes[has_error], errors[has_error])
            self._add(self.pred_error_count, episodes[has_error])
            bins = np.searchsorted(_BIN_STARTS, depth[live][has_error], side="right") - 1
            for b in range(len(DEPTH_BINS)):
                in_bin = bins == b
                self._add(self.depth_sum[b], episodes[has_error][in_bin], errors[has_error][in_bin])
                self._add(self.depth_count[b], episodes[has_error][in_bin])

    def row(self, episode: int) -> dict[str, float]:
        """The diagnostic columns of ``episode`` (see the module docstring)."""

        def mean(total: np.ndarray, count: np.ndarray) -> float:
            return float(total[episode] / count[episode]) if count[episode] > 0 else math.nan

        row = {
            "map_error": mean(self.map_error_sum, self.map_error_count),
            "pred_error_dropout": mean(self.pred_error_sum, self.pred_error_count),
            "dropout_share": mean(self.dropout_steps, self.agent_steps),
            "dropout_run_mean": mean(self.dropout_steps, self.dropout_runs),
        }
        for column, total, count in zip(DEPTH_COLUMNS, self.depth_sum, self.depth_count):
            row[column] = mean(total, count)
        return row
