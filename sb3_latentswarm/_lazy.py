"""Public names loaded on first use (PEP 562), for the package ``__init__`` modules that must not import torch.

    __getattr__, __dir__ = lazy_exports(__name__, {"sb3_latentswarm.latent_ppo": ("LatentSwarmPolicy", "LatentSwarmPPO")})

The module then imports ``sb3_latentswarm.latent_ppo`` the first time ``LatentSwarmPPO`` is asked for, and keeps the
value in its namespace, so later look-ups do not come back here. Type checkers read the names from an
``if TYPE_CHECKING:`` block beside the call, one ``from MODULE import NAMES`` line per entry of the table.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Mapping, Sequence
from typing import Any


def lazy_exports(
    module_name: str, exports: Mapping[str, Sequence[str]]
) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """The module-level ``__getattr__`` and ``__dir__`` of a module whose public names load on first use.

    :param module_name: the module's ``__name__``; it must be in ``sys.modules`` (it is, while its body runs)
    :param exports: defining module -> the public names it defines
    :return: ``(__getattr__, __dir__)``; ``__getattr__`` raises ``AttributeError`` for a name that no module of
        ``exports`` lists, as Python does for any missing module attribute
    :raise ValueError: when two modules list the same name
    """
    module = sys.modules[module_name]
    source = {name: defining for defining, names in exports.items() for name in names}
    if len(source) < sum(len(names) for names in exports.values()):
        raise ValueError(f"lazy_exports({module_name!r}): a name is listed by two modules")

    def __getattr__(name: str) -> Any:
        if name not in source:
            raise AttributeError(f"module {module_name!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(source[name]), name)
        setattr(module, name, value)
        return value

    def __dir__() -> list[str]:
        return sorted({*vars(module), *source})

    return __getattr__, __dir__
