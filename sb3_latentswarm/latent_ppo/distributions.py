"""The actor's action distributions (Sec. III-D): SB3's diagonal Gaussian without argument validation, its
tanh-squashed version with the exact change of variables, and the smooth bound of the std head."""

from __future__ import annotations

import math

import torch as th
import torch.nn.functional as F
from stable_baselines3.common.distributions import DiagGaussianDistribution, SquashedDiagGaussianDistribution, TanhBijector
from torch.distributions import Normal

__all__ = [
    "TanhSquashedGaussianDistribution",
    "action_entropy",
    "UnvalidatedDiagGaussianDistribution",
    "inverse_smooth_log_std",
    "smooth_log_std",
    "unvalidated_normal",
]


def smooth_log_std(raw: th.Tensor, low: float, high: float) -> th.Tensor:
    """log std = low + (high - low) * (tanh(raw) + 1) / 2, CleanRL's SAC bound: smooth, non-zero slope everywhere.

    Computed as ``high - (high - low) * sigmoid(-2 raw)`` for raw >= 0 and ``low + (high - low) * sigmoid(2 raw)``
    below (the same function, since (tanh(x) + 1) / 2 = sigmoid(2x)): ``tanh(raw)`` rounds to exactly +-1 in float32
    once abs(raw) > 9, and its gradient with it, while these forms keep a non-zero gradient up to abs(raw) of about 40
    (where it reaches float32's smallest normal number).

    :param raw: the std head's output, any shape
    :return: the log std, same shape, strictly inside (low, high) for abs(raw) < 9
    """
    span = high - low
    return th.where(raw >= 0, high - span * th.sigmoid(-2.0 * raw), low + span * th.sigmoid(2.0 * raw))


def inverse_smooth_log_std(log_std: float, low: float, high: float) -> float:
    """The raw output that :func:`smooth_log_std` maps to ``log_std`` (which must lie strictly inside (low, high))."""
    return math.atanh(2.0 * (log_std - low) / (high - low) - 1.0)


def unvalidated_normal(mean_actions: th.Tensor, log_std: th.Tensor) -> Normal:
    """SB3's diagonal Gaussian N(mean, exp(log_std)^2), built without ``torch.distributions``' argument validation.

    Validation reads ``bool()`` of tensors (a host sync per check, several per minibatch); the arguments here are
    finite by construction (a linear head and a bounded log std). Per distribution rather than
    ``Distribution.set_default_validate_args(False)``, which would switch it off for the user's code too.
    """
    action_std = th.ones_like(mean_actions) * log_std.exp()
    return Normal(mean_actions, action_std, validate_args=False)


class UnvalidatedDiagGaussianDistribution(DiagGaussianDistribution):
    """SB3's :class:`~stable_baselines3.common.distributions.DiagGaussianDistribution` without argument validation
    (:func:`unvalidated_normal`): the same numbers, no host syncs."""

    def proba_distribution(self, mean_actions: th.Tensor, log_std: th.Tensor) -> UnvalidatedDiagGaussianDistribution:
        self.distribution = unvalidated_normal(mean_actions, log_std)
        return self


class TanhSquashedGaussianDistribution(SquashedDiagGaussianDistribution):
    """SB3's :class:`~stable_baselines3.common.distributions.SquashedDiagGaussianDistribution` (a = tanh(u),
    u ~ N(mean, std^2)) with the exact change of variables in :meth:`log_prob`.

    SB3 subtracts ``log(1 - a^2 + 1e-6)``: the 1e-6 shifts the log-probability of a saturated action by up to 1.6
    nats per dimension, and it flattens the sampled entropy estimate once abs(u) passes about 7, so that estimate stops
    pulling the actor back from saturation. Here log(da/du) = log(1 - tanh(u)^2) = 2 (log 2 - u - softplus(-2u)),
    exact and finite for every u. ``entropy()`` stays ``None`` (no closed form): see
    :meth:`LatentSwarmPolicy.action_entropy`. Built without argument validation (:func:`unvalidated_normal`).
    """

    def proba_distribution(self, mean_actions: th.Tensor, log_std: th.Tensor) -> TanhSquashedGaussianDistribution:
        self.distribution = unvalidated_normal(mean_actions, log_std)
        return self

    def log_prob(self, actions: th.Tensor, gaussian_actions: th.Tensor | None = None) -> th.Tensor:
        """log pi(a) = log N(u; mean, std^2) - sum_k log(1 - tanh(u_k)^2), (B,).

        :param actions: squashed actions a in [-1, 1], (B, action_dim)
        :param gaussian_actions: u with a = tanh(u), when known; otherwise u = atanh(a), with a clipped to
            [-1 + eps, 1 - eps] (float eps) as SB3 does, so that a saturated a = +-1 has a finite log-probability
        """
        if gaussian_actions is None:
            gaussian_actions = TanhBijector.inverse(actions)
        log_prob = DiagGaussianDistribution.log_prob(self, gaussian_actions)
        log_det = 2.0 * (math.log(2.0) - gaussian_actions - F.softplus(-2.0 * gaussian_actions))
        return log_prob - log_det.sum(dim=-1)


def action_entropy(distribution: DiagGaussianDistribution) -> th.Tensor:
    """The entropy of each row of ``distribution``, (B,): exact for the Gaussian; for the squashed Gaussian, which has no
    closed form, the one-sample estimate -log pi(tanh(u)) with a reparameterized u ~ N(mean, std^2), as SB3's SAC does.
    Its gradient is an unbiased estimate of the entropy's gradient (SB3's PPO instead uses -log pi of the stored action,
    whose expected gradient is zero at the rollout's policy). ``LatentSwarmPolicy.action_entropy``."""
    entropy = distribution.entropy()
    if entropy is not None:
        return entropy
    # only the squashed Gaussian has no closed-form entropy; its log_prob takes the pre-squash actions too
    assert isinstance(distribution, SquashedDiagGaussianDistribution)
    gaussian_actions = distribution.distribution.rsample()
    return -distribution.log_prob(th.tanh(gaussian_actions), gaussian_actions)
