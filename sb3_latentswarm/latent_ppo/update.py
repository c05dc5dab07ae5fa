"""One update of :class:`~sb3_latentswarm.latent_ppo.LatentSwarmPPO` (its ``train``): the joint loss of Sec. III-E
on each minibatch, Eq. (2)-(4), the gradient steps, the checks for non-finite values and the ``train/`` logs.

The algorithm's ``train``, ``_minibatch_losses``, ``loss_gradient_norms`` and ``recompute_old_log_probs`` call these
functions; the minibatches come from :class:`~sb3_latentswarm.latent_ppo.buffers.SwarmRolloutBuffer` (whole swarms,
chunks of ``chunk_length`` steps) and the sequence replay from the policy's ``evaluate_sequences``.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np
import torch as th
from stable_baselines3.common.utils import explained_variance

if TYPE_CHECKING:
    from sb3_latentswarm.latent_ppo.latent_ppo import LatentSwarmPPO
    from sb3_latentswarm.latent_ppo.policies import SequenceEvaluation

__all__ = [
    "LOSS_TERMS",
    "NonFiniteLossError",
    "auxiliary_losses",
    "loss_gradient_norms",
    "minibatch_losses",
    "ppo_update",
    "recompute_old_log_probs",
]

LOSS_TERMS = ("policy", "value", "entropy", "map", "pred")
"""The terms of the joint loss, as named in ``train/grad_norm_<term>``."""


class NonFiniteLossError(FloatingPointError):
    """A loss term or a parameter became NaN or infinite during training; the message names the update and the term."""


def auxiliary_losses(evaluation: SequenceEvaluation, referent: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
    """The self-supervised terms of the joint loss.

    Both are averaged per element rather than summed (see the paper-to-code table): a sum over the 2500 cells would
    make c2 = 5 swamp the PPO terms under the global gradient-norm clip.

    :param evaluation: outputs of :meth:`LatentSwarmPolicy.evaluate_sequences`, time-major (T, B, ...)
    :param referent: what D_eta reconstructs for every agent-step: M_hat_t (T, B, H, W) on the swarm env, an adapted
        env's referent (T, B, R)
    :return: (L_map, L_pred)
    """
    # Eq. (3): L_map = 1/(NT) sum_i sum_t ||D(mu_t^i) - M_hat_t||^2
    map_loss = ((evaluation.map_reconstruction - referent.float().flatten(2)) ** 2).mean()
    # Eq. (4): L_pred = mean over t in T_comm^i of ||m_t^i - mhat_t^i||^2; the received m is a target (no gradient)
    pred_error = ((evaluation.predicted_message - evaluation.received_message.detach()) ** 2).mean(-1)
    comm = evaluation.has_message.float()
    pred_loss = (pred_error * comm).sum() / comm.sum().clamp(min=1.0)
    return map_loss, pred_loss


def minibatch_losses(
    model: LatentSwarmPPO, rollout_data: Any, clip_range: float, clip_range_vf: float | None
) -> dict[str, th.Tensor]:
    """The unweighted terms of the joint loss (:data:`LOSS_TERMS`) on one minibatch of ``model``'s rollout buffer, and
    ``log_ratio``, log pi(a_t) - log pi_old(a_t) of its agent-steps."""
    evaluation = model.policy.evaluate_sequences(
        rollout_data.observations,
        rollout_data.actions,
        rollout_data.latent_state,
        rollout_data.episode_starts,
    )
    advantages = rollout_data.advantages
    if model.normalize_advantage and advantages.numel() > 1:
        advantages = (advantages - advantages.mean()) / (advantages.std() + 1e-8)

    # L_CLIP: clipped surrogate objective
    ratio = th.exp(evaluation.log_prob - rollout_data.old_log_prob)
    policy_loss_1 = advantages * ratio
    policy_loss_2 = advantages * th.clamp(ratio, 1 - clip_range, 1 + clip_range)
    policy_loss = -th.min(policy_loss_1, policy_loss_2).mean()

    # L_VF on the critic's scale: the returns R_t (normalized by ValueNorm when it is on), optionally clipped
    # around the old value, squared error (the paper's) or Huber (MAPPO's). With ValueNorm the old values go back
    # to the critic's raw output of the rollout (the statistics they were denormalized with), so the clip compares
    # the critic with itself in one frame, as MAPPO does: nothing is clipped before the first gradient step.
    values, returns, old_values = evaluation.values, rollout_data.returns, rollout_data.old_values
    normalizer = model.policy.value_normalizer
    if normalizer is not None:
        returns, old_values = normalizer.normalize(returns), normalizer.normalize(old_values, frame="rollout")
    if clip_range_vf is not None:
        values = old_values + th.clamp(values - old_values, -clip_range_vf, clip_range_vf)
    if model.value_loss == "huber":
        value_loss = th.nn.functional.huber_loss(values, returns, delta=model.huber_delta)
    else:
        value_loss = ((returns - values) ** 2).mean()

    referent = rollout_data.observations[model.policy.layout.referent_key]
    map_loss, pred_loss = auxiliary_losses(evaluation, referent)
    return {
        "policy": policy_loss,
        "value": value_loss,
        "entropy": -evaluation.entropy.mean(),
        "map": map_loss,
        "pred": pred_loss,
        "log_ratio": evaluation.log_prob - rollout_data.old_log_prob,
    }


def loss_gradient_norms(model: LatentSwarmPPO, losses: dict[str, th.Tensor]) -> dict[str, float]:
    """L2 norm, over all parameters, of the gradient of each weighted loss term (before any clipping)."""
    weights = model._loss_weights()
    parameters = [p for p in model.policy.parameters() if p.requires_grad]
    norms = {}
    for term in LOSS_TERMS:
        grads = th.autograd.grad(weights[term] * losses[term], parameters, retain_graph=True, allow_unused=True)
        squared = th.zeros((), device=model.device)
        for grad in grads:
            if grad is not None:
                squared = squared + (grad.detach() ** 2).sum()
        norms[term] = float(th.sqrt(squared))
    return norms


def _raise_non_finite(model: LatentSwarmPPO, losses: dict[str, th.Tensor], update: int, epoch: int, minibatch: int) -> None:
    """Raise :class:`NonFiniteLossError` naming the first non-finite loss term, the update, the epoch and the
    minibatch (counted over the update's epochs)."""
    for term in LOSS_TERMS:
        value = float(losses[term].detach())
        if not math.isfinite(value):
            raise NonFiniteLossError(
                f"the {term} loss is {value} in update {update} (epoch {epoch + 1}, minibatch {minibatch}); lower "
                f"learning_rate (now {model.policy.optimizer.param_groups[0]['lr']:g}) or check the rewards and "
                f"observations"
            )
    raise NonFiniteLossError(f"the weighted sum of the loss terms overflows in update {update} (epoch {epoch + 1}, "
                             f"minibatch {minibatch}); lower the loss weights or check the rewards")


def recompute_old_log_probs(model: LatentSwarmPPO) -> None:
    """Replace the rollout's log-probabilities log pi_old(a_t) in the buffer by those of the training forward pass
    (:meth:`LatentSwarmPolicy.sequence_log_prob`, no gradient) with the same parameters, on minibatches of
    ``batch_size``: under bf16 autocast the rollout's step-by-step forward rounds differently (about 1e-4 in log pi),
    and the PPO ratio of the first gradient step must be exactly 1. A bf16 GEMM's rows depend on the number of rows
    but not on which other rows share the minibatch, so the replay of any minibatch of the same size reproduces
    these values. Called by :func:`ppo_update` when ``autocast`` is set; the float32 replay already matches the rollout
    (to about 1e-6).
    """
    policy = model.policy

    def replayed(batch: Any) -> th.Tensor:
        return policy.sequence_log_prob(batch.observations, batch.actions, batch.latent_state, batch.episode_starts)

    with th.no_grad():
        model.rollout_buffer.replace_log_probs(model.batch_size, replayed)


def ppo_update(model: LatentSwarmPPO) -> None:
    """One update of ``model`` on its rollout buffer (its ``train``): the joint loss of Sec. III-E, one gradient step per
    minibatch, ``n_epochs`` times (SB3's early stop on ``target_kl``), then the ``train/`` logs.

    :raise NonFiniteLossError: when a loss term or a parameter becomes NaN or infinite, naming it
    """
    model.policy.set_training_mode(True)
    model._update_learning_rate(model.policy.optimizer)
    clip_range = model.clip_range(model._current_progress_remaining)  # type: ignore[operator]
    clip_range_vf = None if model.clip_range_vf is None else model.clip_range_vf(model._current_progress_remaining)  # type: ignore[operator]
    if model.policy.value_normalizer is not None:
        model.policy.value_normalizer.update(th.as_tensor(model.rollout_buffer.returns, device=model.device))

    if model.policy.autocast is not None:
        model.recompute_old_log_probs()
    weights = model._loss_weights()
    update = model.num_timesteps // (model.n_steps * model.n_envs)  # this update's number, counting rollouts from 1
    parameter_groups = model._parameter_groups()
    # per minibatch, kept on the device and read once per epoch (a host sync each, a device sync on a GPU): the loss
    # terms, approx_kl and the clip fraction (term_stats); the gradient norm of each parameter group (norm_stats)
    term_stats: list[list[float]] = []
    norm_stats: list[list[float]] = []
    grad_norms: dict[str, float] = {}
    continue_training = True
    loss = th.zeros(())

    for epoch in range(model.n_epochs):
        epoch_terms: list[th.Tensor] = []
        epoch_norms: list[th.Tensor] = []
        for rollout_data in model.rollout_buffer.get(model.batch_size):
            losses = model._minibatch_losses(rollout_data, clip_range, clip_range_vf)
            loss = sum(weights[term] * losses[term] for term in LOSS_TERMS)  # type: ignore[assignment]
            # the one host sync of a minibatch: a non-finite loss must stop training before it reaches the weights
            if not bool(th.isfinite(loss)):
                _raise_non_finite(model, losses, update, epoch, len(term_stats) + len(epoch_terms) + 1)
            if model.log_grad_norms and not grad_norms:
                grad_norms = model.loss_gradient_norms(losses)

            with th.no_grad():
                log_ratio = losses["log_ratio"]
                ratio = th.exp(log_ratio)
                approx_kl_div = th.mean((ratio - 1) - log_ratio)
                clip_fraction = th.mean((th.abs(ratio - 1) > clip_range).float())
                terms = [losses[term].detach() for term in LOSS_TERMS]
                epoch_terms.append(th.stack([*terms, approx_kl_div, clip_fraction]))

            # SB3's early stop reads approx_kl every minibatch, only when target_kl is set
            if model.target_kl is not None and float(approx_kl_div) > 1.5 * model.target_kl:
                continue_training = False
                if model.verbose >= 1:
                    print(f"Early stopping at step {epoch} due to reaching max kl: {float(approx_kl_div):.2f}")
                break

            model.policy.optimizer.zero_grad()
            loss.backward()
            epoch_norms.append(th.stack([th.nn.utils.clip_grad_norm_(g, model.max_grad_norm) for g in parameter_groups]))
            model.policy.optimizer.step()

        term_stats += th.stack(epoch_terms).tolist() if epoch_terms else []
        norm_stats += th.stack(epoch_norms).tolist() if epoch_norms else []
        model._n_updates += 1
        if not continue_training:
            break
    parameters = list(model.policy.parameters())
    if not bool(th.stack([th.isfinite(p).all() for p in parameters]).all()):
        bad = [name for name, p in model.policy.named_parameters() if not bool(th.isfinite(p).all())]
        raise NonFiniteLossError(
            f"parameters {bad[:3]} became NaN or infinite in update {update} (the losses were finite: the step was "
            f"too large); lower learning_rate (now {model.policy.optimizer.param_groups[0]['lr']:g})"
        )

    means = dict(zip((*LOSS_TERMS, "approx_kl", "clip_fraction"), np.mean(term_stats, axis=0)))
    explained_var = explained_variance(model.rollout_buffer.values.flatten(), model.rollout_buffer.returns.flatten())
    model.logger.record("train/entropy_loss", means["entropy"])
    model.logger.record("train/policy_gradient_loss", means["policy"])
    model.logger.record("train/value_loss", means["value"])
    model.logger.record("train/map_loss", means["map"])
    model.logger.record("train/pred_loss", means["pred"])
    model.logger.record("train/approx_kl", means["approx_kl"])
    model.logger.record("train/clip_fraction", means["clip_fraction"])
    model.logger.record("train/loss", loss.item())
    model.logger.record("train/explained_variance", explained_var)
    model.logger.record("train/n_updates", model._n_updates, exclude="tensorboard")
    model.logger.record("train/clip_range", clip_range)
    if norm_stats:
        mean_norms = np.mean(norm_stats, axis=0)
        names = ["grad_norm"] if model.grad_clip == "global" else ["grad_norm_actor", "grad_norm_critic"]
        for name, value in zip(names, mean_norms):
            model.logger.record(f"train/{name}", float(value))
    for term, value in grad_norms.items():
        model.logger.record(f"train/grad_norm_{term}", value)
    if not model.policy.state_dependent_std:
        log_std = model.policy.bound_log_std(model.policy.log_std.detach())
        model.logger.record("train/std", float(log_std.exp().mean()))
    if model.policy.value_normalizer is not None:
        mean, var = model.policy.value_normalizer.mean_var()
        model.logger.record("train/value_norm_mean", float(mean))
        model.logger.record("train/value_norm_std", float(var.sqrt()))
    if clip_range_vf is not None:
        model.logger.record("train/clip_range_vf", clip_range_vf)
