"""Checks a model file must pass before anything it declares is allocated: the memory its sizes would take, and the
agreement of its stored env config with its observation space.

A model file declares its network widths, observation space and rollout length as numbers; each number is bounded on
its own (:mod:`sb3_latentswarm.latent_ppo.model_file`), but together they could still ask for many GiB. The policy is
therefore built first on PyTorch's ``meta`` device (shapes only, no memory), and the file is refused when the policy
with its gradients and Adam state, plus the rollout buffer once there is an env to train on, would take more than
:data:`MAX_LOAD_BYTES`.
"""

from __future__ import annotations

import math
from typing import Any

import torch as th
from gymnasium import spaces

__all__ = [
    "MAX_INT_DIGITS", "MAX_LOAD_BYTES", "MAX_MODEL_BYTES", "bounded_int", "check_config_matches_space",
    "check_load_budget", "estimate_load_bytes",
]

MAX_INT_DIGITS = 64
"""Most digits of an integer in a model file's ``data`` entry or a checkpoint's ``state.json`` (a PCG64 state has 39):
longer ones are refused while parsing, with a message naming the file (Python's own digit limit names none)."""

MAX_MODEL_BYTES = 2**30
"""Largest memory (bytes) the model of a file may need by its declared sizes, without a rollout buffer: 1 GiB. Counted:
16 bytes per policy parameter (weights, gradients, Adam's two moments) and the policy's buffers. The ``paper`` preset's
model (hidden 512) needs about 152 MiB."""

MAX_LOAD_BYTES = 8 * 2**30
"""Largest memory (bytes) a model loaded with an env to train on may need: 8 GiB. Counted: the model
(:data:`MAX_MODEL_BYTES`) and twice its rollout buffer (``n_steps`` of the file times the env's slots, each with its
observations, action, values and latent states: the buffer and its minibatch tensors). The ``paper`` preset (600 steps,
120 slots) needs about 2.5 GiB."""

_FLOATS_PER_STEP = 8  # reward, value, log-prob, advantage, return, episode start, has-message, spare


def bounded_int(text: str) -> int:
    """``json.loads``'s ``parse_int``: an integer of at most :data:`MAX_INT_DIGITS` digits, else ``ValueError``."""
    if len(text.lstrip("-")) > MAX_INT_DIGITS:
        raise ValueError(f"an integer of {len(text.lstrip('-'))} digits (the limit is {MAX_INT_DIGITS})")
    return int(text)


def _space_bytes(space: spaces.Space) -> int:
    if isinstance(space, spaces.Dict):
        return sum(_space_bytes(sub) for sub in space.spaces.values())
    return math.prod(space.shape or ()) * space.dtype.itemsize  # type: ignore[union-attr]


def estimate_load_bytes(model: Any, n_envs: int | None = None) -> int | None:
    """The memory ``model`` (built with ``_init_setup_model=False``, its saved attributes restored) needs once set up,
    from its declared sizes only: the policy built on the ``meta`` device, and the rollout buffer for ``n_envs`` slots.

    :return: bytes; ``None`` for a policy class that cannot be built on the ``meta`` device (sb3-contrib's recurrent
        policy, used by :class:`~sb3_latentswarm.baselines.IndependentRecurrentPPO`: its widths are bounded one by one)
    :raise ValueError: when the declared policy cannot be built
    """
    try:
        with th.device("meta"):
            policy = model.policy_class(model.observation_space, model.action_space, lambda _: 0.0, **model.policy_kwargs)
    except (RuntimeError, NotImplementedError) as error:
        if "meta" in str(error):
            return None
        raise ValueError(f"the model the file declares cannot be built: {error}") from None
    except (TypeError, ValueError, KeyError) as error:
        raise ValueError(f"the model the file declares cannot be built: {error}") from None
    parameters = sum(p.numel() for p in policy.parameters())
    total = 16 * parameters + sum(b.numel() * b.element_size() for b in policy.buffers())
    if n_envs is not None:
        latent = sum(getattr(policy, "latent_dims", ()))
        per_step = _space_bytes(model.observation_space) + 4 * (
            math.prod(model.action_space.shape or ()) + latent + _FLOATS_PER_STEP
        )
        total += 2 * int(model.n_steps) * int(n_envs) * per_step
    return int(total)


def check_load_budget(model: Any, path: Any, n_envs: int | None = None) -> None:
    """Refuse ``model`` (from the file ``path``) when :func:`estimate_load_bytes` is over :data:`MAX_MODEL_BYTES`, or,
    with the ``n_envs`` slots of an env to train on, over :data:`MAX_LOAD_BYTES`.

    :raise ValueError: naming the file, the estimate and the limit
    """
    checks: list[tuple[int | None, int, str, str]] = [(None, MAX_MODEL_BYTES, "MAX_MODEL_BYTES", "the model")]
    if n_envs is not None:
        checks.append((n_envs, MAX_LOAD_BYTES, "MAX_LOAD_BYTES", "the model and its rollout buffer"))
    for slots, limit, name, what in checks:
        try:
            need = estimate_load_bytes(model, slots)
        except ValueError as error:
            raise ValueError(f"{path}: {error}") from None
        if need is not None and need > limit:
            raise ValueError(
                f"{path}: by its declared sizes {what} would take about {need / 2**30:.1f} GiB, more than the limit of "
                f"{limit / 2**30:g} GiB (sb3_latentswarm.latent_ppo.load_checks.{name}); refused before allocating"
            )


def check_config_matches_space(swarm_config: Any, observation_space: Any, path: Any) -> None:
    """Refuse a file whose stored ``swarm_config`` gives another observation space than the one it stores.

    :raise ValueError: naming the file and each observation that differs
    """
    from sb3_latentswarm.envs.batched_core import agent_observation_space

    if swarm_config is None or not isinstance(observation_space, spaces.Dict):
        return
    expected = agent_observation_space(swarm_config)
    differ = [
        f"{key}: the config gives {expected[key].shape if key in expected.spaces else 'nothing'}, the file stores "
        f"{observation_space[key].shape if key in observation_space.spaces else 'nothing'}"
        for key in sorted(set(expected.spaces) | set(observation_space.spaces))
        if key not in expected.spaces
        or key not in observation_space.spaces
        or expected[key].shape != observation_space[key].shape
    ]
    if differ:
        raise ValueError(
            f"{path}: data entry 'swarm_config' does not match 'observation_space' ({'; '.join(differ)}); refused"
        )
