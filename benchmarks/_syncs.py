"""Counting host syncs: the places where the host waits for a value the device computed.

On a GPU, ``torch.cuda.set_sync_debug_mode("warn")`` flags them; on a CPU nothing ever waits, so a profiler's
``aten::_local_scalar_dense`` count (every ``.item()``) also counts reads that never wait on a device, such as Adam's
step counters, which torch keeps on the host (``capturable=False``, the default). :class:`SyncCounter` counts with the
GPU's semantics on both kinds of device, from the Python calls (a ``TorchFunctionMode``):

* reads of a tensor's value by the host: ``.item()``, ``float()``, ``bool()``, ``int()``, ``operator.index``,
  ``.tolist()``, ``.cpu()`` (and ``.numpy()`` of a tensor that did not just come from ``.cpu()``: on a GPU ``.numpy()``
  only ever runs on a host copy);
* ops whose output shape depends on the values (``nonzero``, ``argwhere``, ``masked_select``, ``unique``,
  ``unique_consecutive``, indexing with a boolean mask, ``repeat_interleave`` with tensor repeats, ``equal``,
  ``allclose``): the host must learn the size;

and not counted:

* reads made inside ``torch.optim`` (the optimizer's step counters live on the host);
* on a CUDA run, reads of tensors that are already on the CPU.

Syncs made inside C++ kernels without a Python call (none in this package's hot path) are not seen.
"""

from __future__ import annotations

import collections
import os
import pathlib
import sys
from typing import Any

import torch as th
from torch.overrides import TorchFunctionMode

READS = ("item", "__float__", "__bool__", "__int__", "__index__", "tolist", "cpu", "numpy")
"""Tensor methods that hand a tensor's value to the host."""
DATA_DEPENDENT = ("nonzero", "argwhere", "masked_select", "unique", "unique_consecutive", "_unique2", "equal", "allclose")
"""Functions whose output (shape or Python value) depends on the values: the host waits for them."""
_OPTIM = f"torch{os.sep}optim{os.sep}"


def _has_mask(index: Any) -> bool:
    """Whether a ``__getitem__``/``__setitem__`` index holds a boolean tensor (a data-dependent shape)."""
    items = index if isinstance(index, tuple) else (index,)
    return any(isinstance(i, th.Tensor) and i.dtype == th.bool and i.dim() > 0 for i in items)


class SyncCounter(TorchFunctionMode):
    """Counts host syncs (see the module's docstring) by call site (``file:line name``) while active.

    :param device: the device the run computes on; on ``cuda`` reads of CPU tensors are not syncs. On ``cpu`` every
        read outside ``torch.optim`` counts: it would wait for the device on a GPU.
    """

    def __init__(self, device: th.device | str = "cpu") -> None:
        super().__init__()
        self.on_gpu = th.device(device).type != "cpu"
        self.sites: collections.Counter[str] = collections.Counter()
        self._last_cpu: int | None = None

    @property
    def count(self) -> int:
        return sum(self.sites.values())

    def _is_sync(self, name: str, args: tuple[Any, ...], kwargs: dict[str, Any]) -> bool:
        tensor = args[0] if args and isinstance(args[0], th.Tensor) else None
        if name in READS:
            if name == "numpy" and (self.on_gpu or (tensor is not None and id(tensor) == self._last_cpu)):
                return False  # .cpu().numpy() is one transfer; on a GPU .numpy() reads a host copy
        elif name in DATA_DEPENDENT:
            pass
        elif name in ("__getitem__", "__setitem__"):
            if len(args) < 2 or not _has_mask(args[1]):
                return False
        elif name == "repeat_interleave":
            repeats = args[1] if len(args) > 1 else kwargs.get("repeats")
            if not isinstance(repeats, th.Tensor) or kwargs.get("output_size") is not None:
                return False
        else:
            return False
        return not (self.on_gpu and tensor is not None and tensor.device.type == "cpu")

    def __torch_function__(self, func, types, args=(), kwargs=None):  # noqa: ANN001 - torch's protocol
        kwargs = kwargs or {}
        name = getattr(func, "__name__", "")
        sync = self._is_sync(name, args, kwargs)
        result = func(*args, **kwargs)
        if sync:
            frame = sys._getframe(1)
            if _OPTIM not in frame.f_code.co_filename:
                self.sites[f"{pathlib.Path(frame.f_code.co_filename).name}:{frame.f_lineno} {name}"] += 1
        self._last_cpu = id(result) if name == "cpu" else None
        return result
