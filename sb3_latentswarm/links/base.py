"""The one interface of the link models: which directed links deliver at step t, for a batch of swarms.

Convention (that of the observation key ``link_row``): ``mask[s, i, j] = True`` iff the message of sender ``j``
reached receiver ``i`` in swarm ``s`` at this step (row = receiver, column = sender); the diagonal is always
``False``. ``age[s, i, j]`` is how many steps late that message arrived (0: on time, the paper's case), defined only
where the mask is ``True`` (0 elsewhere) and only for models with delay (``None`` otherwise).

Random streams: a model draws from the generators it is handed, one per swarm of the batch (the core's per-swarm
streams), swarm by swarm, so a swarm's links do not depend on the batch size or its slot in the batch.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

__all__ = ["ALL", "LinkModel", "LinkStep", "Swarms", "offdiagonal"]

#: Swarm selection: an index array, or :data:`ALL` (a slice: views instead of gathered copies).
Swarms = np.ndarray | slice
ALL = slice(None)


class LinkStep(NamedTuple):
    """What a link model delivers at one step, for ``K`` swarms of ``N`` UAVs.

    :param mask: (K, N, N) bool, ``[s, i, j]`` = the message of ``j`` reached ``i``.
    :param age: (K, N, N) int16, steps by which that message is late (0 where nothing arrived), or ``None`` for models
        without delay (every delivered message is on time).
    """

    mask: np.ndarray
    age: np.ndarray | None


def offdiagonal(n: int) -> np.ndarray:
    """Read-only boolean (n, n) mask, ``True`` off the diagonal (a UAV does not receive its own message)."""
    mask = ~np.eye(n, dtype=bool)
    mask.flags.writeable = False
    return mask


class LinkModel(ABC):
    """Which directed links of ``n_swarms`` swarms of ``n_agents`` UAVs deliver at each step (VMAS style: state
    arrays carry a leading swarm dimension, reset in place per swarm).

    A model with memory (a Gilbert-Elliott chain, messages in flight) keeps it here, and hands it out with
    :meth:`get_state` / :meth:`set_state` so that a checkpoint resumes the same episodes exactly.

    :param n_swarms: B, the number of swarms.
    :param n_agents: N, the UAVs per swarm.
    """

    #: Whether :meth:`step` reads the positions (distance and A2A models); others accept ``None``.
    needs_positions: bool = False
    #: Whether :meth:`step` returns the age of what arrived (the delay model).
    has_delay: bool = False

    def __init__(self, n_swarms: int, n_agents: int) -> None:
        self.n_swarms = int(n_swarms)
        self.n_agents = int(n_agents)
        self._offdiagonal = offdiagonal(self.n_agents)

    @abstractmethod
    def step(
        self,
        swarms: Swarms,
        rngs: Sequence[np.random.Generator],
        positions: np.ndarray | None,
        distances2: np.ndarray | None = None,
    ) -> LinkStep:
        """Draw this step's deliveries of swarms ``swarms`` and advance their link state.

        :param swarms: the swarms stepped (:data:`ALL` or an index array of length K).
        :param rngs: one generator per stepped swarm, in the order of ``swarms``.
        :param positions: (K, N, 3) positions in metres (``None`` allowed when :attr:`needs_positions` is False).
        :param distances2: (K, N, N) squared distances of ``positions`` if the caller has them already.
        """

    def reset(self, swarms: Swarms) -> None:
        """Forget the link state of swarms ``swarms`` (a new episode); called before their first :meth:`step`."""
        return None  # a model without memory has nothing to forget

    def get_state(self) -> dict[str, np.ndarray]:
        """The model's state arrays (copies), keyed by name; empty for a model without memory."""
        return {name: array.copy() for name, array in self._state_arrays().items()}

    def set_state(self, state: dict[str, np.ndarray]) -> None:
        """Restore what :meth:`get_state` returned.

        :raises ValueError: a key is missing or unknown, or an array has another shape or dtype.
        """
        own = self._state_arrays()
        if set(state) != set(own):
            raise ValueError(f"{type(self).__name__} state has keys {sorted(own)}, got {sorted(state)}")
        for name, current in own.items():
            saved = np.asarray(state[name])
            if saved.shape != current.shape or saved.dtype != current.dtype:
                raise ValueError(
                    f"{type(self).__name__} state {name!r} must be {current.dtype} of shape {current.shape}, got "
                    f"{saved.dtype} of shape {saved.shape}"
                )
        for name, current in own.items():
            current[...] = state[name]

    def _state_arrays(self) -> dict[str, np.ndarray]:
        """The live state arrays (not copies); :meth:`get_state` and :meth:`set_state` are built on it."""
        return {}
