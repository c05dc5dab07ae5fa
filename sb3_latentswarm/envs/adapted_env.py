"""An adapted env by name, as plain data: what ``train --env``, ``evaluate --env`` and ``sweep --env`` run on.

:class:`AdaptedEnv` names a PettingZoo ``ParallelEnv`` and its keyword arguments; with the link fields of a
:class:`~sb3_latentswarm.config.SwarmConfig` (``link_model``, ``link_mode``, ``p_fail``, ``outage_model``,
``mean_outage_steps``, ``link_range``, ...) it builds the VecEnv of
:func:`~sb3_latentswarm.envs.parallel_adapter.make_adapted_vec_env`. The same preset, ``--set`` names and test-time
conditions then apply as on the swarm env: a condition replaces the config's ``link_mode`` and ``p_fail``.

A name is one of two kinds:

* a **registered name** (:data:`REGISTERED_ENVS`), e.g. ``mpe2:simple_spread_v3``: code of this package says how to
  build it and what it measures (positions for distance links, ``simple_spread``'s landmarks covered and collisions).
  A registered name may be read back from a file (a checkpoint's settings, ``sweep.json``, ``evaluation.json``);
* a **Python entry point** ``package.module:function``, like gymnasium's ``entry_point``: ``function(**env_kwargs)``
  returns the env. Importing it runs the user's code, so it is honoured only where the user names it (on the command
  line or in Python), never when it is read from a file: a model, checkpoint or sweep file never names code to import
  (``docs/security.md``). :meth:`AdaptedEnv.from_record` enforces this. An entry point gives no positions (so no
  distance or A2A links) and no metrics beyond the episode return and length; for those, call
  :func:`~sb3_latentswarm.envs.make_adapted_vec_env` from Python with ``position_fn`` and ``metrics_fn``.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib
import json
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from sb3_latentswarm.config import SwarmConfig
from sb3_latentswarm.envs import mpe

__all__ = ["ENTRY_POINT_FORM", "REGISTERED_ENVS", "AdaptedEnv", "RegisteredEnv", "link_spec_fields", "parse_env_kwargs"]


@dataclass(frozen=True)
class RegisteredEnv:
    """How this package builds a named env: ``module.function(**defaults, **env_kwargs)``, its helpers and its extra."""

    module: str
    function: str
    defaults: Mapping[str, Any] = field(default_factory=dict)
    """Keyword arguments given unless ``env_kwargs`` sets them (MPE2: ``continuous_actions=True``)."""
    position_fn: Callable[[Any], Any] | None = None
    metrics_fn: Callable[[Any], dict[str, float]] | None = None
    extra: str = ""
    """The package extra that installs it (named in the error when the import fails)."""


REGISTERED_ENVS: Mapping[str, RegisteredEnv] = {
    "mpe2:simple_spread_v3": RegisteredEnv(
        "mpe2.simple_spread_v3", "parallel_env", {"continuous_actions": True}, mpe.mpe_positions,
        mpe.simple_spread_metrics, "mpe",
    ),
}
"""The env names a file may hold: each one's factory and helpers are code of this package."""

ENTRY_POINT_FORM = "package.module:function"
_ENTRY_POINT = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*:[A-Za-z_][A-Za-z0-9_]*$")
_NOT_LINK_FIELDS = ("n_agents", "extra")


def link_spec_fields(config: SwarmConfig) -> dict[str, Any]:
    """The fields of ``config`` that a :class:`~sb3_latentswarm.envs.LinkSpec` takes (all but ``n_agents``: the
    adapter sets it from the env)."""
    return {f.name: getattr(config, f.name) for f in dataclasses.fields(SwarmConfig) if f.name not in _NOT_LINK_FIELDS}


def parse_env_kwargs(text: str | None, option: str = "--env-kwargs") -> dict[str, Any]:
    """``--env-kwargs``' JSON object as a dict (``None``: empty).

    :raise ValueError: not JSON, or not an object, naming ``option``
    """
    if text is None:
        return {}
    try:
        value = json.loads(text)
    except json.JSONDecodeError as error:
        raise ValueError(f"{option} must be a JSON object such as '{{\"N\": 3}}', got {text!r} ({error.msg})") from None
    if not isinstance(value, dict):
        raise ValueError(f"{option} must be a JSON object such as '{{\"N\": 3}}', got {type(value).__name__} {text!r}")
    return value


@dataclass(frozen=True)
class AdaptedEnv:
    """A PettingZoo ``ParallelEnv`` by name (see the module docstring) and its keyword arguments.

    :param name: a registered name (:data:`REGISTERED_ENVS`) or an entry point ``package.module:function``
    :param kwargs: keyword arguments of the env's function (JSON values)
    :raise ValueError: a name of neither kind, or keyword arguments that are not a JSON object
    """

    name: str
    kwargs: Mapping[str, Any] = field(default_factory=dict)
    named_by_user: bool = field(default=True, compare=False, repr=False)
    """Named on the command line or in Python (``True``), or read from a file (:meth:`from_dict`): then an entry
    point is never imported (:meth:`env_fn` raises)."""

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not (self.name in REGISTERED_ENVS or _ENTRY_POINT.match(self.name)):
            raise ValueError(
                f"--env must be a registered env ({', '.join(REGISTERED_ENVS)}) or a Python entry point "
                f"{ENTRY_POINT_FORM} returning a PettingZoo ParallelEnv, got {self.name!r}"
            )
        if not isinstance(self.kwargs, Mapping) or not all(isinstance(k, str) for k in self.kwargs):
            raise ValueError(f"--env-kwargs must be a JSON object with string keys, got {self.kwargs!r}")
        try:
            json.dumps(dict(self.kwargs))
        except (TypeError, ValueError):
            raise ValueError(f"--env-kwargs must hold JSON values only, got {self.kwargs!r}") from None
        object.__setattr__(self, "kwargs", dict(self.kwargs))

    @property
    def entry_point(self) -> bool:
        """Whether :attr:`name` is the user's entry point (not a registered name)."""
        return self.name not in REGISTERED_ENVS

    def to_dict(self) -> dict[str, Any]:
        """``{"env": name, "env_kwargs": kwargs}``, as run settings and records store it."""
        return {"env": self.name, "env_kwargs": dict(self.kwargs)}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> AdaptedEnv:
        """The env of :meth:`to_dict`'s output read from a file: a registered name builds as usual, an entry point is
        data only (:meth:`env_fn` refuses to import it; the command must name it again, :meth:`from_record`)."""
        name = data["env"]
        return cls(name, data.get("env_kwargs") or {}, named_by_user=name in REGISTERED_ENVS)

    @classmethod
    def from_record(cls, record: Mapping[str, Any], given: AdaptedEnv | None, source: str) -> AdaptedEnv | None:
        """The env a file records (``{"env": ..., "env_kwargs": ...}``), honouring the security rule: an entry point
        read from a file is refused unless the command names the same one.

        :param given: the env the command line names (``None``: none)
        :param source: the file, for the messages
        :return: ``None`` when the record names no env (the swarm env)
        :raise ValueError: an entry point not given on the command line, or a given env that differs
        """
        if record.get("env") is None:
            return None
        stored = cls.from_dict(record)
        if given is not None and given != stored:
            raise ValueError(f"--env {given.name} {json.dumps(given.kwargs)} differs from {source}'s "
                             f"{stored.name} {json.dumps(stored.kwargs)}")
        if given is not None:
            return given
        if stored.entry_point:
            raise ValueError(
                f"{source} names the entry point {stored.name!r}; a file never names code to import (docs/security.md): "
                f"pass --env {stored.name} --env-kwargs '{json.dumps(stored.kwargs)}' to run it"
            )
        return stored

    def env_fn(self) -> Callable[[], Any]:
        """A function making one env copy (the entry point or the registered module is imported here).

        :raise ValueError: the module cannot be imported or has no such function (with the extra to install)
        """
        registered = REGISTERED_ENVS.get(self.name)
        if registered is None and not self.named_by_user:
            raise ValueError(
                f"the entry point {self.name!r} was read from a file, which never names code to import "
                f"(docs/security.md): pass --env {self.name} --env-kwargs '{json.dumps(self.kwargs)}' to run it"
            )
        module_name, function_name = (registered.module, registered.function) if registered else self.name.split(":")
        try:
            module = importlib.import_module(module_name)
        except ImportError as error:
            hint = f" (install it: pip install 'sb3-latentswarm[{registered.extra}]')" if registered else ""
            raise ValueError(f"--env {self.name}: cannot import {module_name}: {error}{hint}") from None
        function = getattr(module, function_name, None)
        if not callable(function):
            raise ValueError(f"--env {self.name}: {module_name} has no function {function_name!r}")
        kwargs = {**(registered.defaults if registered else {}), **self.kwargs}
        return functools.partial(function, **kwargs)

    def make_vec_env(self, n_envs: int, config: SwarmConfig, seed: int | None = 0, monitor: bool = True) -> Any:
        """The adapted VecEnv of ``n_envs`` copies with the link model of ``config``'s link fields
        (:func:`link_spec_fields`; ``config.n_agents`` is not used: the env says how many agents it has).

        :param seed: copy ``c`` resets with ``seed + c``
        :raise ValueError, TypeError: from the adapter (spaces, shapes, a link model needing positions the env lacks)
        """
        from sb3_latentswarm.envs.parallel_adapter import LinkSpec, make_adapted_vec_env

        registered = REGISTERED_ENVS.get(self.name)
        return make_adapted_vec_env(
            self.env_fn(), n_envs, link_model=LinkSpec(**link_spec_fields(config)),
            position_fn=registered.position_fn if registered else None,
            metrics_fn=registered.metrics_fn if registered else None, seed=seed, monitor=monitor,
        )

    def probe(self) -> tuple[int, bool]:
        """N (``len(possible_agents)``) and whether the first agent's actions are in [-1, 1], read from one env copy
        (built and closed).

        :raise ValueError: the env cannot be built with these keyword arguments
        """
        try:
            env = self.env_fn()()
        except TypeError as error:
            raise ValueError(f"--env {self.name} with --env-kwargs {json.dumps(self.kwargs)}: {error}") from None
        try:
            agents = list(env.possible_agents)
            space = env.action_space(agents[0]) if agents else None
            low, high = getattr(space, "low", None), getattr(space, "high", None)
            symmetric = low is not None and high is not None and bool((low == -1).all() and (high == 1).all())
            return len(agents), symmetric
        finally:
            env.close()
