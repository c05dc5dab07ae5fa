"""Link models: which directed links deliver at each step, for a batch of swarms, behind one interface
(:class:`~sb3_latentswarm.links.LinkModel`). Which ``j -> i`` deliver, by ``SwarmConfig``:

* A2A channel, Eq. (1): ``link_model="a2a"`` (default, the paper's): ``Gamma_{j->i} >= beta_th`` and ``xi = 1``;
* Bernoulli: ``link_model="outage"``: ``xi = 1`` with ``xi ~ Bernoulli(1 - p_f)`` per directed link and step;
* Gilbert-Elliott: ``link_model="outage"``, ``outage_model="gilbert_elliott"``: ``xi = 1``, a Markov chain per link;
* distance: ``link_model="distance"``: ``||p_i - p_j|| <= link_range`` (3D, metres) and ``xi = 1``;
* delay (wraps any of them): ``message_delay > 0``: it got through ``d <= message_expiry`` steps ago.

``outage_model`` chooses xi for every model that draws it. ``link_mode`` still selects the ablations: ``"full"``
(every link up), ``"none"`` (every link down) and ``"full_in_range"`` (every link within the model's range up: the
channel's usable range for ``"a2a"``, ``link_range`` for ``"distance"``, every link for ``"outage"``).
"""

from __future__ import annotations

from sb3_latentswarm.channel import usable_link_range
from sb3_latentswarm.config import SwarmConfig
from sb3_latentswarm.links.base import ALL, LinkModel, LinkStep, Swarms
from sb3_latentswarm.links.delay import DELAY_MODELS, DelayedLinks, draw_delays
from sb3_latentswarm.links.models import A2ALinks, DistanceLinks, FixedLinks, OutageLinks, Outages

__all__ = [
    "ALL",
    "DELAY_MODELS",
    "A2ALinks",
    "DelayedLinks",
    "DistanceLinks",
    "FixedLinks",
    "LinkModel",
    "LinkStep",
    "OutageLinks",
    "Outages",
    "Swarms",
    "draw_delays",
    "make_link_model",
]


def make_link_model(config: SwarmConfig, n_swarms: int) -> LinkModel:
    """The link model ``config`` selects (see the table above), for ``n_swarms`` swarms."""
    base: LinkModel
    n = config.n_agents
    if config.link_mode == "full" or (config.link_mode == "full_in_range" and config.link_model == "outage"):
        base = FixedLinks(n_swarms, n, up=True)
    elif config.link_mode == "none":
        base = FixedLinks(n_swarms, n, up=False)
    elif config.link_mode == "full_in_range":
        link_range = config.link_range if config.link_model == "distance" else usable_link_range(config)
        base = DistanceLinks(config, n_swarms, link_range, outages=False)
    elif config.link_model == "a2a":
        base = A2ALinks(config, n_swarms)
    elif config.link_model == "distance":
        base = DistanceLinks(config, n_swarms, config.link_range)
    elif config.link_model == "outage":
        base = OutageLinks(config, n_swarms)
    else:  # SwarmConfig validates the value: a new model needs its branch here
        raise ValueError(f"link_model {config.link_model!r} has no branch in make_link_model")
    if config.message_delay == 0:
        return base
    return DelayedLinks(base, config.message_delay, config.message_delay_model, config.message_expiry)
