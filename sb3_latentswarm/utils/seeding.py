"""Env seeds of training seeds: one rule for ``sweep`` and ``train --seeds``; the action-noise stream of an evaluation
episode (a light module: no torch, no SB3).

A training seed ``k`` trains ``n_envs`` env copies. Copy ``c`` of a run whose first copy has seed ``base`` is seeded
with ``base + c`` (:meth:`~sb3_latentswarm.presets.Preset.make_env`). With ``base = k`` (what ``train --seed k``
does), neighbouring training seeds share ``n_envs - 1`` copies: copy 1 of seed 0 is copy 0 of seed 1. With
``base = k * n_envs`` (:func:`training_env_seed`), the copies of different training seeds are disjoint.
"""

from __future__ import annotations

import numpy as np

from sb3_latentswarm.utils.checks import check_int

__all__ = ["ACTION_NOISE_STREAM", "WARM_START_SEED_STRIDE", "action_noise_rng", "training_env_seed", "warm_start_seed"]

ACTION_NOISE_STREAM = 0x5EED
"""Separates the action-noise stream of episode seed s from the env's stream of s (:func:`action_noise_rng`)."""

WARM_START_SEED_STRIDE = 500_000
"""Seed offset of a continued run (``sweep --warm-start``): the ``d``-th continuation of a run seeds its model and its env
copies ``d * WARM_START_SEED_STRIDE`` higher than the run itself, so it does not replay the episodes and the random
numbers the run began with; still below the held-out evaluation seeds (1,000,000) for ``d = 1``."""


def training_env_seed(train_seed: int, n_envs: int) -> int:
    """Base seed of the training env copies of training seed ``train_seed`` (copy ``c``: base + ``c``).

    ``train_seed * n_envs``: the copies ``k * n_envs .. (k + 1) * n_envs - 1`` of training seed ``k`` meet no other
    training seed's copies. Used by ``sweep`` trials and by each seed of ``train --seeds``.

    :param train_seed: the training seed (the model's seed), >= 0
    :param n_envs: env copies per run, >= 1
    :return: the seed of env copy 0
    :raises TypeError, ValueError: ``train_seed`` not an int >= 0, ``n_envs`` not an int >= 1
    """
    return check_int("train_seed", train_seed, low=0) * check_int("n_envs", n_envs, low=1)


def warm_start_seed(seed: int, depth: int) -> int:
    """The seed of the ``depth``-th continuation of a run seeded ``seed``: ``seed + depth * WARM_START_SEED_STRIDE``.

    :param seed: a model seed or the seed of env copy 0 (:func:`training_env_seed`), >= 0
    :param depth: 0 for the run itself, 1 for a run that continues it (``sweep --warm-start``), 2 for one that continues
        that, ...
    :raises TypeError, ValueError: ``seed`` or ``depth`` not an int >= 0
    """
    return check_int("seed", seed, low=0) + check_int("depth", depth, low=0) * WARM_START_SEED_STRIDE


def action_noise_rng(episode_seed: int) -> np.random.Generator:
    """The generator of a sampled episode's action noise: ``default_rng([episode_seed, ACTION_NOISE_STREAM])``, one
    ``(N, action_dim)`` standard-normal draw per step, row i for UAV i (the evaluation runner's protocol; a UAV process
    draws the same rows on its own)."""
    return np.random.default_rng([episode_seed, ACTION_NOISE_STREAM])
