"""Public names loaded on first use (PEP 562), for the package ``__init__`` modules that must not import torch.

    __getattr__, __dir__ = lazy_exports(__name__, {"LatentSwarmPPO": "sb3_latentswarm.latent_ppo", ...})

The module then imports ``sb3_latentswarm.latent_ppo`` the first time ``LatentSwarmPPO`` is asked for, and keeps the
value in its namespace, so later look-ups do not come back here. Type checkers read the names from an
``if TYPE_CHECKING:`` import block beside the call.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Mapping
from typing import Any


def lazy_exports(module_name: str, exports: Mapping[str, str]) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """The module-level ``__getattr__`` and ``__dir__`` of a module whose public names load on first use.

    :param module_name: the module's ``__name__``; it must be in ``sys.modules`` (it is, while its body runs)
    :param exports: public name -> the module that defines it under that name
    :return: ``(__getattr__, __dir__)``; ``__getattr__`` raises ``AttributeError`` for a name not in ``exports``,
        as Python does for any missing module attribute
    """
    module = sys.modules[module_name]

    def __getattr__(name: str) -> Any:
        if name not in exports:
            raise AttributeError(f"module {module_name!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(exports[name]), name)
        setattr(module, name, value)
        return value

    def __dir__() -> list[str]:
        return sorted({*vars(module), *exports})

    return __getattr__, __dir__
