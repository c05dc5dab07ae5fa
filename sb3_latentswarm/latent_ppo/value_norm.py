"""``ValueNorm``: running normalization of value targets, as MAPPO's (marlbenchmark/on-policy, ``utils/valuenorm.py``).

The critic learns ``(R - mean) / std`` instead of the raw return R, so the value loss keeps the same scale whatever
the reward scale and however returns grow during training. Statistics are debiased exponential moving averages of
the returns' first and second moments, updated once per PPO update. They are registered buffers: they live in the
policy's ``state_dict`` and are saved and loaded with its weights.

The values stored in a rollout were denormalized with the statistics of the rollout; :meth:`update` then moves the
statistics. :meth:`normalize` with ``frame="rollout"`` maps stored values back with the statistics they were made with,
i.e. to the critic's raw output at rollout time, so that PPO's clipped value loss compares the critic with its own old
output in one frame (as MAPPO does, which clips around the stored raw critic output).
"""

from __future__ import annotations

import torch as th
from torch import nn


class ValueNorm(nn.Module):
    """Debiased exponential running mean and variance of scalar value targets.

    :param beta: weight of the old statistics at each update, in (0, 1); one update per PPO update
    :param epsilon: floor of the debiasing term
    :param min_variance: floor of the variance (MAPPO: 1e-2), so a near-constant return does not blow up the targets
    """

    # registered buffers (declared for type checkers: ``nn.Module.__getattr__`` is typed ``Tensor | Module``)
    running_mean: th.Tensor
    running_mean_sq: th.Tensor
    debiasing_term: th.Tensor
    rollout_mean: th.Tensor
    rollout_var: th.Tensor

    def __init__(self, beta: float = 0.995, epsilon: float = 1e-5, min_variance: float = 1e-2) -> None:
        super().__init__()
        if not 0.0 < beta < 1.0:
            raise ValueError(f"ValueNorm beta must be in (0, 1), got {beta}")
        self.beta = beta
        self.epsilon = epsilon
        self.min_variance = min_variance
        self.register_buffer("running_mean", th.zeros(()))
        self.register_buffer("running_mean_sq", th.zeros(()))
        self.register_buffer("debiasing_term", th.zeros(()))
        # the statistics before the last update: the frame of the values stored in the rollout (not saved)
        self.register_buffer("rollout_mean", th.zeros(()), persistent=False)
        self.register_buffer("rollout_var", th.ones(()), persistent=False)

    def mean_var(self) -> tuple[th.Tensor, th.Tensor]:
        """The debiased mean and variance (0 and 1 before the first update), 0-d tensors.

        Chosen with ``th.where``, not a Python ``if`` on a tensor: no host sync (a device synchronization on a GPU).
        """
        debias = self.debiasing_term.clamp(min=self.epsilon)
        mean = self.running_mean / debias
        mean_sq = self.running_mean_sq / debias
        var = (mean_sq - mean**2).clamp(min=self.min_variance)
        started = self.debiasing_term > 0
        return th.where(started, mean, th.zeros_like(mean)), th.where(started, var, th.ones_like(var))

    @th.no_grad()
    def update(self, targets: th.Tensor) -> None:
        """Fold a batch of value targets (any shape) into the running statistics."""
        targets = targets.detach().float()
        mean, var = self.mean_var()
        self.rollout_mean.copy_(mean)
        self.rollout_var.copy_(var)
        self.running_mean.mul_(self.beta).add_((1.0 - self.beta) * targets.mean())
        self.running_mean_sq.mul_(self.beta).add_((1.0 - self.beta) * (targets**2).mean())
        self.debiasing_term.mul_(self.beta).add_(1.0 - self.beta)

    def normalize(self, values: th.Tensor, frame: str = "current") -> th.Tensor:
        """(R - mean) / std.

        :param frame: ``"current"``: with the current statistics (value targets); ``"rollout"``: with the statistics
            before the last :meth:`update`, those the rollout's stored values were denormalized with
        """
        if frame == "rollout":
            return (values - self.rollout_mean) / th.sqrt(self.rollout_var)
        if frame != "current":
            raise ValueError(f"frame must be 'current' or 'rollout', got {frame!r}")
        mean, var = self.mean_var()
        return (values - mean) / th.sqrt(var)

    def denormalize(self, values: th.Tensor) -> th.Tensor:
        """The inverse of :meth:`normalize`: the critic's output back in return units."""
        mean, var = self.mean_var()
        return values * th.sqrt(var) + mean
