"""Checks of ``LatentSwarmPolicy``'s arguments, with error messages that name the bad value and what to use instead."""

from __future__ import annotations

import inspect
from collections.abc import Callable
from typing import Any, cast

import numpy as np
from gymnasium import spaces

from sb3_latentswarm.envs.observations import (
    ACTOR_OBS_KEYS,
    LINK_AGE_KEY,
    STATE_OBS_KEYS,
    ObservationLayout,
    observation_layout,
)

__all__ = ["REQUIRED_KEYS", "check_delay_aware", "check_log_std_bounds", "check_observation_space", "space_shape",
           "unexpected_kwargs_message"]

REQUIRED_KEYS = ACTOR_OBS_KEYS + STATE_OBS_KEYS
"""The observation keys the policy reads on the swarm env: the actor's and the critic's (adapted envs:
:func:`~sb3_latentswarm.envs.observations.observation_layout`)."""


SB3_POLICY_KWARGS = {
    "net_arch": "predictor_hidden, decoder_hidden, critic_hidden, actor_hidden (one width each)",
    "lstm_hidden_size": "latent_dim (d_mu = d_tau = d_rho), or map_dim, task_dim, memory_dim",
    "n_lstm_layers": "none: the latent state is one GRU cell per part (Sec. III-B)",
    "shared_lstm": "none: the critic reads the global state, not the latent state",
    "enable_critic_lstm": "none: the critic reads the global state, not the latent state",
    "activation_fn": "none: the MLPs use tanh",
    "features_extractor_class": "none: the encoders are fixed by the observation keys",
}
"""SB3 / sb3-contrib ``policy_kwargs`` names and what ``LatentSwarmPolicy`` takes instead, for the error message."""


def unexpected_kwargs_message(unexpected: set[str], init: Callable[..., Any]) -> str:
    """``TypeError`` text for unknown ``policy_kwargs``: the valid names, and what to use instead of SB3's names."""
    internal = {"self", "observation_space", "action_space", "lr_schedule", "unused_kwargs"}
    valid = [name for name in inspect.signature(init).parameters if name not in internal]
    hints = "".join(f"; {name} -> {SB3_POLICY_KWARGS[name]}" for name in sorted(unexpected) if name in SB3_POLICY_KWARGS)
    return (
        f"LatentSwarmPolicy got unexpected keyword argument(s) {sorted(unexpected)}{hints}. "
        f"Valid policy_kwargs are: {', '.join(valid)}"
    )


def check_log_std_bounds(bounds: Any) -> tuple[float, float]:
    try:
        low, high = (float(b) for b in bounds)
    except (TypeError, ValueError):
        raise TypeError(f"log_std_bounds must be a pair of numbers (low, high), got {bounds!r}") from None
    if not (np.isfinite(low) and np.isfinite(high) and low < high):
        raise ValueError(f"log_std_bounds must be finite with low < high, got {bounds!r}")
    return low, high


def space_shape(space: spaces.Space) -> tuple[int, ...]:
    """``space.shape``, which gymnasium types as optional (None for spaces without a fixed shape)."""
    if space.shape is None:
        raise ValueError(f"LatentSwarmPolicy needs observation spaces with a fixed shape, got {space}")
    return space.shape


def check_observation_space(observation_space: spaces.Space) -> ObservationLayout:
    """Raise a clear error when the observation space lacks what the latent-swarm policy reads; return its layout."""
    layout = observation_layout(observation_space)
    assert isinstance(observation_space, spaces.Dict)  # observation_layout raised otherwise
    for key in layout.actor_keys + layout.state_keys:
        if not isinstance(observation_space[key], spaces.Box):
            raise TypeError(f"LatentSwarmPolicy needs Box spaces; observation {key!r} is {observation_space[key]}")
    return layout


def check_delay_aware(delay_aware: Any, observation_space: spaces.Dict,
                      layout: ObservationLayout) -> tuple[bool, int, ObservationLayout]:
    """``delay_aware`` checked against the observation space: ``(delay_aware, E, layout)``.

    With delayed links (the ``link_age`` key in the space) every policy pools each arrival as it was sent, so E is
    the expiry (the upper bound of ``link_age``) and the layout's actor keys are extended by ``link_age``, whatever
    ``delay_aware`` says; ``delay_aware`` only adds the age input. Without the key: E = 0 and the layout unchanged.

    :raise TypeError: ``delay_aware`` is not a bool
    :raise ValueError: ``delay_aware=True`` without the ``link_age`` key (links without delay)
    """
    if not isinstance(delay_aware, (bool, np.bool_)):
        raise TypeError(f"delay_aware must be a bool, got {delay_aware!r}")
    if LINK_AGE_KEY not in observation_space.spaces:
        if delay_aware:
            raise ValueError(f"delay_aware=True reads the observation key {LINK_AGE_KEY!r} (links with delay: "
                             f"SwarmConfig.message_delay > 0, or a delayed link model in the adapter); the observation "
                             f"space has {list(observation_space.spaces)}")
        return False, 0, layout
    expiry = int(np.max(cast(spaces.Box, observation_space[LINK_AGE_KEY]).high))
    return bool(delay_aware), expiry, layout._replace(actor_keys=layout.actor_keys + (LINK_AGE_KEY,))
