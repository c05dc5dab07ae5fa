"""The test-time conditions of Sec. IV as one public table: what each one does to the links and to the policy.

Paper conditions (Sec. IV, "To assess each proposed component's contribution, we compare five conditions"):

================  =========================================================================================
``proposed``      the complete framework; links drawn from the A2A channel of Eq. (1) with failure prob. p_f
``full_comm``     every directed link forced up at every step (``link_mode="full"``): coordination upper bound
``no_comm``       every link forced down (``link_mode="none"``): lower bound, every step is a dropout
``no_predictor``  channel links; the predicted message mhat_t is replaced by a zero vector during dropout
``no_memory``     channel links; the memory state rho_t is zeroed before it is used in any update
================  =========================================================================================

Extensions (:data:`EXTRA_CONDITIONS`, not in Table I and not in the default set of
:func:`~sb3_latentswarm.evaluation.evaluate_conditions`; pass them in ``conditions`` to report them):

======================  ===================================================================================
``full_comm_in_range``  every link up whose 3D length is within the channel's usable range, every longer link
                        down (``link_mode="full_in_range"``, range :func:`~sb3_latentswarm.channel.usable_link_range`,
                        set by ``SwarmConfig.link_range_probability``): Full comm without delivering messages from
                        peers so far away that the trained policy never received one (with distance-limited links
                        "a message arrived" is also a proximity cue)
``hold_last``           channel links; during dropout the last message actually received in the episode (zero
                        before the first) replaces mhat_t: the baseline a predictor must beat
``own_message``         channel links; during dropout the agent's own message z_{t-1}^i replaces mhat_t
======================  ===================================================================================

Each condition sets the policy's ``message_substitute``
(:data:`~sb3_latentswarm.latent_ppo.policies.MESSAGE_SUBSTITUTES`) only if it names one (``no_predictor``: ``"zero"``,
``hold_last``, ``own_message``); the others keep the policy's own (the predictor for a model trained as the paper
does; zeros for a ``zero_substitute`` learner, the held message for a ``hold_last`` one).
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Iterator, Mapping
from types import MappingProxyType

from sb3_latentswarm.config import SwarmConfig
from sb3_latentswarm.latent_ppo.policies import LatentSwarmPolicy
from sb3_latentswarm.utils.checks import check_float

__all__ = [
    "CONDITIONS",
    "CONDITION_LABELS",
    "CONDITION_TABLE",
    "EXTRA_CONDITIONS",
    "Condition",
    "check_condition",
    "check_p_fail",
    "condition_config",
    "policy_switches",
]


@dataclasses.dataclass(frozen=True)
class Condition:
    """One test-time condition: the env's link mode and the switches it sets on a latent-swarm policy."""

    name: str
    """Its name, as passed to :func:`~sb3_latentswarm.evaluation.evaluate` (``condition=``)."""
    label: str
    """Its row label in Table I."""
    link_mode: str
    """``SwarmConfig.link_mode`` of the evaluation env: ``"channel"`` (the config's link model at p_f: the A2A channel of
    Eq. (1) by default, or the outage or distance model), ``"full"``, ``"none"`` or ``"full_in_range"``."""
    message_substitute: str | None = None
    """``LatentSwarmPolicy.message_substitute`` under the condition (what replaces m_t during dropout), or ``None``:
    the policy's own."""
    no_memory: bool = False
    """``LatentSwarmPolicy.no_memory``: rho_t is zeroed before use."""
    in_paper: bool = True
    """One of the five conditions of Sec. IV (Table I)."""

    @property
    def switches_policy(self) -> bool:
        """Whether the condition switches off a component of the latent-swarm policy (so a model without one, a
        planner or the independent learner, cannot be evaluated under it)."""
        return self.message_substitute is not None or self.no_memory


_TABLE = (
    Condition("proposed", "Proposed (full)", "channel"),
    Condition("full_comm", "Full comm (UB)", "full"),
    Condition("no_comm", "No comm (LB)", "none"),
    Condition("no_predictor", "No predictor", "channel", message_substitute="zero"),
    Condition("no_memory", "No memory", "channel", no_memory=True),
    Condition("full_comm_in_range", "Full comm in range", "full_in_range", in_paper=False),
    Condition("hold_last", "Hold last message", "channel", message_substitute="hold_last", in_paper=False),
    Condition("own_message", "Own message", "channel", message_substitute="own_message", in_paper=False),
)
CONDITION_TABLE: Mapping[str, Condition] = MappingProxyType({c.name: c for c in _TABLE})
"""Every test-time condition by name (read-only): the paper's five, then the extensions."""
CONDITIONS = tuple(c.name for c in _TABLE if c.in_paper)
"""The five test-time conditions of Sec. IV (Table I, and the default of ``evaluate_conditions``)."""
EXTRA_CONDITIONS = tuple(c.name for c in _TABLE if not c.in_paper)
"""Conditions beyond the paper (see the module docstring); accepted wherever a condition is."""
CONDITION_LABELS = MappingProxyType({c.name: c.label for c in _TABLE})
"""Row labels of Table I."""


def check_condition(condition: str) -> Condition:
    """The :class:`Condition` named ``condition``; ``ValueError`` listing the allowed names otherwise."""
    if not isinstance(condition, str) or condition not in CONDITION_TABLE:
        raise ValueError(f"Unknown condition {condition!r}; allowed conditions: {list(CONDITION_TABLE)}")
    return CONDITION_TABLE[condition]


def check_p_fail(p_fail: float) -> float:
    """``p_fail`` as a float in [0, 1], or ``TypeError``/``ValueError``."""
    return check_float("p_fail", p_fail, 0.0, 1.0)


def condition_config(config: SwarmConfig, condition: str, p_fail: float) -> SwarmConfig:
    """The env configuration of ``condition``: its link mode (Sec. IV) and the link failure probability ``p_fail``."""
    return config.replace(link_mode=check_condition(condition).link_mode, p_fail=check_p_fail(p_fail))


@contextlib.contextmanager
def policy_switches(policy: LatentSwarmPolicy, condition: str) -> Iterator[LatentSwarmPolicy]:
    """Set the ablation switches of ``condition`` on ``policy`` (and eval mode); restore them on exit.

    Every condition sets ``no_memory``, so ``proposed`` also turns off a memory ablation left on by the caller; the
    substitute is set only by the conditions that name one (``no_predictor``, ``hold_last``, ``own_message``).
    """
    spec = check_condition(condition)
    saved = (policy.message_substitute, policy.no_memory, policy.training)
    if spec.message_substitute is not None:
        policy.message_substitute = spec.message_substitute
    policy.no_memory = spec.no_memory
    policy.set_training_mode(False)
    try:
        yield policy
    finally:
        policy.message_substitute, policy.no_memory = saved[0], saved[1]
        policy.set_training_mode(saved[2])
