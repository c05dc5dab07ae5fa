"""Named training/evaluation budgets: ``paper`` (the paper's setting verbatim), ``fast`` (a documented reduction for a
2-core CPU), ``coordination`` (a scenario on which coordination is necessary, see ``docs/env.md``), ``random_corner``
(``coordination`` with N = 5, the launch corner drawn per episode, T = 48 and bursty outages: no message-free convention
can split the work), ``demo`` (the README's main job, about two minutes) and ``smoke`` (seconds, for the test suite).

Each preset is a :class:`Preset`: an env config, the ``LatentSwarmPPO`` keyword arguments, the training budget and the
evaluation budget. ``docs/concepts.md`` explains each reduction.
"""

from __future__ import annotations

import dataclasses
import difflib
import textwrap
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from sb3_latentswarm.config import SwarmConfig
from sb3_latentswarm.latent_ppo.schedules import paper_learning_rate

if TYPE_CHECKING:
    from sb3_latentswarm.envs.adapted_env import AdaptedEnv


@dataclass(frozen=True)
class Preset:
    """A complete experiment budget."""

    name: str
    config: SwarmConfig
    """The env of training and evaluation."""
    n_envs: int
    """Env copies (swarms) trained in parallel."""
    total_timesteps: int
    """Training budget in agent-steps (SB3's ``num_timesteps`` counts vec-env slots)."""
    algo_kwargs: dict[str, Any] = field(default_factory=dict)
    """Keyword arguments of ``LatentSwarmPPO`` (``policy_kwargs`` included)."""
    eval_episodes: int = 10
    """Monte Carlo runs per condition and per p_f value (paper: 10)."""
    p_fails: tuple[float, ...] = (0.0, 0.05, 0.15, 0.3, 0.5)
    """The p_f sweep of Table I (right)."""
    baseline_timesteps: int = 0
    """Training budget (agent-steps) of the independent RecurrentPPO baseline; 0 skips it."""
    description: str = ""
    env: AdaptedEnv | None = None
    """An adapted env to run on instead of the swarm env (``--env``, :meth:`with_env`): :attr:`config` then gives its
    link model (``link_model``, ``link_mode``, ``p_fail``, ...) and ``n_agents`` (the env's); ``None``: the swarm env."""

    def with_env(self, env: AdaptedEnv | None, keep_links: bool = False) -> Preset:
        """This preset's algorithm settings and budget on the adapted env ``env`` (``None``: unchanged).

        The config takes the env's number of agents and, until a ``--set`` changes it, Bernoulli outages
        (``link_model="outage"``, at the preset's ``p_fail``): the A2A channel of Eq. (1) is in metres, which another
        env's positions need not be. An env whose actions are not in [-1, 1] (MPE2: [0, 1]) gets the paper's Gaussian
        actor (``action_distribution="gaussian"``, clipped to the box as SB3's PPO clips), SB3's default for such a
        box; ``--set action_distribution=squashed_gaussian`` (applied after this) gives the CPU presets' squashed
        Gaussian rescaled to the box instead (:meth:`LatentSwarmPolicy.env_actions
        <sb3_latentswarm.LatentSwarmPolicy.env_actions>`). Builds one env copy to read its agents and action space.

        :param keep_links: keep the config's ``link_model`` (a saved run's config) instead of Bernoulli outages

        :raise ValueError: the env cannot be built (see :meth:`AdaptedEnv.n_agents
            <sb3_latentswarm.envs.adapted_env.AdaptedEnv.n_agents>`)
        """
        if env is None:
            return self
        n_agents, symmetric_actions = env.probe()
        config = self.config.replace(n_agents=n_agents, link_model=self.config.link_model if keep_links else "outage")
        algo_kwargs = self.algo_kwargs
        if not symmetric_actions and algo_kwargs.get("policy_kwargs", {}).get("action_distribution") == "squashed_gaussian":
            policy_kwargs = {**algo_kwargs["policy_kwargs"], "action_distribution": "gaussian"}
            algo_kwargs = {**algo_kwargs, "policy_kwargs": policy_kwargs}
        return dataclasses.replace(self, env=env, config=config, algo_kwargs=algo_kwargs)

    @property
    def updates(self) -> int:
        """Number of rollout/update iterations the budget gives."""
        return max(1, -(-self.total_timesteps // self.agent_steps_per_update))

    def independent_ppo_kwargs(self) -> dict[str, Any]:
        """``RecurrentPPO`` keyword arguments giving the ``independent`` baseline this preset's PPO settings.

        The settings both algorithms share (:data:`SHARED_PPO_SETTINGS`: rollout length, minibatch, epochs, learning
        rate, discount, GAE, clip range, entropy and value coefficients, gradient clip) take the values
        ``LatentSwarmPPO`` trains ``proposed`` with (this preset's ``algo_kwargs``, else ``LatentSwarmPPO``'s
        defaults), and the policy's initial log std is the preset's ``log_std_init``. sb3-contrib's policy has a
        state-independent, unbounded log std: no bound can be passed (``docs/evaluation.md`` lists what differs).

        :return: keyword arguments of :func:`~sb3_latentswarm.baselines.train_independent_ppo`
        """
        import inspect

        from sb3_latentswarm.latent_ppo import LatentSwarmPolicy, LatentSwarmPPO

        defaults = inspect.signature(LatentSwarmPPO.__init__).parameters
        kwargs = {name: self.algo_kwargs.get(name, defaults[name].default) for name in SHARED_PPO_SETTINGS}
        log_std_init = self.algo_kwargs.get("policy_kwargs", {}).get(
            "log_std_init", inspect.signature(LatentSwarmPolicy.__init__).parameters["log_std_init"].default
        )
        kwargs["policy_kwargs"] = dict(log_std_init=log_std_init)
        return kwargs

    @property
    def agent_steps_per_update(self) -> int:
        """Agent-steps one rollout/update iteration collects: ``n_steps * n_envs * n_agents``."""
        return int(self.algo_kwargs["n_steps"]) * self.n_envs * self.config.n_agents

    def make_env(self, seed: int | None = 0, *, config: SwarmConfig | None = None, backend: str = "batched") -> Any:
        """The preset's training ``VecEnv``: :attr:`n_envs` swarms of :attr:`config` (or ``config``), one slot per agent.

        The one path from a preset to an env (the CLI, the sweep trials, the examples and the benchmarks use it). With
        :attr:`env`, the adapted VecEnv of that env with ``config``'s link model.

        :param seed: base seed: swarm copy ``c`` uses ``seed + c``
        :param config: another env config (e.g. ``link_mode="none"`` for the ``no_comm`` learner); default the preset's
        :param backend: ``"batched"`` (one vectorized core) or ``"supersuit"``
        :return: an SB3 ``VecMonitor`` with ``num_envs = n_envs * n_agents``
        :raise ValueError: for a bad config, backend or ``n_envs`` (from :func:`~sb3_latentswarm.envs.make_vec_env`)
        """
        config = self.config if config is None else config
        if self.env is not None:
            if backend != "batched":
                raise ValueError(f"backend {backend!r} steps the swarm env only; an adapted env (--env) has its own VecEnv")
            return self.env.make_vec_env(self.n_envs, config, seed)
        from sb3_latentswarm.envs import make_vec_env

        return make_vec_env(self.n_envs, config=config, seed=seed, backend=backend)

    def make_model(self, env: Any, *, seed: int | None = 0, **kwargs: Any) -> Any:
        """``LatentSwarmPPO("LatentSwarmPolicy", env, seed=seed, **algo_kwargs)`` with :attr:`algo_kwargs` and ``kwargs``.

        The one path from a preset to a model. ``kwargs`` (``device``, ``verbose``, ``tensorboard_log``, ...) are added
        to the preset's arguments; a name in both takes the value of ``kwargs``.

        :param env: the env of :meth:`make_env` (or any VecEnv of the same config)
        :raise ValueError, TypeError: for bad settings (from ``LatentSwarmPPO`` and its policy)
        """
        from sb3_latentswarm.latent_ppo import LatentSwarmPPO

        return LatentSwarmPPO("LatentSwarmPolicy", env, seed=seed, **{**self.algo_kwargs, **kwargs})

    def with_overrides(self, **overrides: Any) -> Preset:
        """A copy with settings replaced, each routed by its name (see :func:`override_targets`).

        ``SwarmConfig`` fields are validated here by ``SwarmConfig`` itself; ``LatentSwarmPPO`` and
        ``LatentSwarmPolicy`` arguments are validated by their constructors when the model is built.

        :raise UnknownSettingError: (a ``TypeError``) for a name that is none of those, naming its closest valid names
            (:func:`check_setting_names`)
        """
        check_setting_names(sorted(overrides))
        targets = override_targets()
        pick = {target: {k: v for k, v in overrides.items() if k in names} for target, names in targets.items()}
        algo_kwargs = {**self.algo_kwargs, **pick["LatentSwarmPPO"]}
        if pick["LatentSwarmPolicy"]:
            algo_kwargs["policy_kwargs"] = {**self.algo_kwargs.get("policy_kwargs", {}), **pick["LatentSwarmPolicy"]}
        return dataclasses.replace(
            self, config=self.config.replace(**pick["SwarmConfig"]), algo_kwargs=algo_kwargs, **pick["Preset"]
        )


SHARED_PPO_SETTINGS = ("learning_rate", "n_steps", "batch_size", "n_epochs", "gamma", "gae_lambda", "clip_range",
                       "normalize_advantage", "ent_coef", "vf_coef", "max_grad_norm", "target_kl")
"""Arguments that ``LatentSwarmPPO`` and sb3-contrib's ``RecurrentPPO`` share, with the same meaning (``n_steps`` per
vec-env slot, ``batch_size`` in agent-steps)."""

PRESET_SETTINGS = ("n_envs", "eval_episodes")
"""Fields of :class:`Preset` that ``--set`` may replace."""

_NOT_OVERRIDABLE = ("self", "policy", "env", "device", "_init_setup_model", "policy_kwargs", "tensorboard_log", "verbose",
                    "seed", "observation_space", "action_space", "lr_schedule", "optimizer_class")


def override_targets() -> dict[str, tuple[str, ...]]:
    """The names that :meth:`Preset.with_overrides` (and the CLI's ``--set``) accept, by where each one goes.

    Taken from the code (the dataclass fields and the constructors' signatures), so new options need no change here.
    ``seed``, ``verbose``, ``tensorboard_log`` and ``device`` have CLI flags of their own. A name that both
    ``LatentSwarmPPO`` and ``LatentSwarmPolicy`` take (``normalize_value``: the algorithm sets its policy's) is listed,
    and routed, once: under ``LatentSwarmPPO``, which passes it on to the policy.
    """
    import inspect

    from sb3_latentswarm.latent_ppo import LatentSwarmPolicy, LatentSwarmPPO

    def arguments(function) -> tuple[str, ...]:
        parameters = inspect.signature(function).parameters.values()
        return tuple(p.name for p in parameters if p.kind is p.POSITIONAL_OR_KEYWORD and p.name not in _NOT_OVERRIDABLE)

    algorithm = arguments(LatentSwarmPPO.__init__)
    return {
        "SwarmConfig": tuple(f.name for f in dataclasses.fields(SwarmConfig) if f.name != "extra"),
        "Preset": PRESET_SETTINGS,
        "LatentSwarmPPO": algorithm,
        "LatentSwarmPolicy": tuple(name for name in arguments(LatentSwarmPolicy.__init__) if name not in algorithm),
    }


LIST_SETTINGS_COMMAND = "sb3-latentswarm train --list-settings"
"""The command that prints every setting name, by target (:func:`format_settings`)."""


def unknown_settings_message(unknown: Sequence[str]) -> str:
    """The error text for setting names that :func:`override_targets` does not know: each name with its three closest
    valid names (``difflib.get_close_matches``) and where the full list is (:data:`LIST_SETTINGS_COMMAND`).

    :param unknown: the unknown names, in the order to report them
    :return: e.g. ``unknown setting 'lerning_rate' (did you mean learning_rate?); `sb3-latentswarm train
        --list-settings` lists every setting``
    """
    valid = [name for names in override_targets().values() for name in names]
    described = []
    for name in unknown:
        close = difflib.get_close_matches(name, valid, n=3)
        described.append(f"{name!r}" + (f" (did you mean {', '.join(close)}?)" if close else " (no close match)"))
    plural = "s" if len(described) > 1 else ""
    return f"unknown setting{plural} {', '.join(described)}; `{LIST_SETTINGS_COMMAND}` lists every setting"


class UnknownSettingError(TypeError, ValueError):
    """A setting name that no target of :func:`override_targets` takes: a ``TypeError``, as an unexpected keyword
    argument is in Python, and a ``ValueError``, as bad input on the command line is."""


def check_setting_names(names: Sequence[str], what: str = "") -> None:
    """The one check of setting names: ``--set``, ``--grid``, ``--eval-set``, :meth:`Preset.with_overrides` and
    :meth:`SweepSpec.create <sb3_latentswarm.experiments.SweepSpec.create>` call it.

    :param names: the names, in the order to report them
    :param what: where they come from (``--grid``), the message's prefix
    :raise UnknownSettingError: naming each unknown name with its closest valid names (:func:`unknown_settings_message`)
    """
    valid = {name for target in override_targets().values() for name in target}
    unknown = [name for name in dict.fromkeys(names) if name not in valid]
    if unknown:
        message = unknown_settings_message(unknown)
        raise UnknownSettingError(f"{what}: {message}" if what else message)


def format_settings(width: int = 100) -> str:
    """Every name that ``--set`` (and :meth:`Preset.with_overrides`) accepts, one paragraph per target of
    :func:`override_targets`, names sorted, wrapped to ``width`` characters."""
    where = {
        "SwarmConfig": "the env (Sec. II; `evaluate` and `render` too)",
        "Preset": "the run (n_envs: `train` only)",
        "LatentSwarmPPO": "the algorithm (`train` only)",
        "LatentSwarmPolicy": "the policy, as policy_kwargs (`train` only)",
    }
    paragraphs = []
    for target, names in override_targets().items():
        title = f"{target}: {where.get(target, '')}".rstrip(": ")
        body = textwrap.fill(", ".join(sorted(names)), width=width, initial_indent="  ", subsequent_indent="  ")
        paragraphs.append(f"{title}\n{body}")
    return "\n\n".join(paragraphs)


MAPPO_TRAINING: dict[str, Any] = dict(normalize_value=True, value_loss="huber", grad_clip="per_group")
"""The MAPPO habits the CPU presets train with (docs/algorithm.md, "Training options"; measured in
docs/results/archive/training_options_fast/): the critic's gradient no longer scales down the actor's and the latent
losses'."""
BOUNDED_STD: dict[str, Any] = dict(log_std_bounds=(-5.0, 0.0), log_std_init=-0.5)
"""Policy std at most 1 (half the action box), initially 0.61: most sampled actions fall inside the box."""
PAPER_ACTOR: dict[str, Any] = dict(action_distribution="gaussian", log_std_mapping="tanh")
"""The actor of the ``paper`` preset: the paper's Gaussian (Sec. III-D), its log std bounded smoothly
(``docs/algorithm.md``, "The actor"; ``log_std_mapping="clamp"`` is the bound of the models trained before it existed)."""
ACTOR: dict[str, Any] = dict(action_distribution="squashed_gaussian", log_std_mapping="tanh")
"""The actor of the CPU presets (with :data:`MAPPO_TRAINING`): the tanh-squashed Gaussian, chosen by measurement on
``coordination`` (docs/results/archive/actor_choice/: with mean actions its collisions stay within 1.3x the sampled ones
and its means never leave the box, where the Gaussian's mean actions collided 4.7x more than its samples). ``--set
action_distribution=gaussian`` trains the paper's Gaussian instead."""


def _algo_kwargs(
    *, n_steps: int, chunk_length: int, batch_size: int, latent_dim: int, hidden: int, mappo: bool = False, **extra: Any
) -> dict:
    kwargs: dict[str, Any] = dict(
        n_steps=n_steps,
        chunk_length=chunk_length,
        batch_size=batch_size,
        policy_kwargs=dict(
            latent_dim=latent_dim,
            predictor_hidden=hidden,
            decoder_hidden=hidden,
            critic_hidden=hidden,
            actor_hidden=min(hidden, 64),
            **(ACTOR if mappo else PAPER_ACTOR),
            **(BOUNDED_STD if mappo else {}),
        ),
    )
    if mappo:
        kwargs.update(MAPPO_TRAINING)
    kwargs.update(extra)
    return kwargs


def _paper() -> Preset:
    n_envs, n_steps, updates = 40, 600, 1600
    config = SwarmConfig()
    return Preset(
        name="paper",
        config=config,
        n_envs=n_envs,
        total_timesteps=updates * n_steps * n_envs * config.n_agents,
        algo_kwargs=_algo_kwargs(
            n_steps=n_steps,
            chunk_length=25,
            batch_size=4500,
            latent_dim=512,
            hidden=256,
            learning_rate=paper_learning_rate(updates, 1000),
            autocast="bf16",  # 1.39x per training minibatch on this CPU (benchmarks/minibatch_ops.py, docs/algorithm.md)
        ),
        baseline_timesteps=updates * n_steps * n_envs * config.n_agents,
        description="Sec. IV verbatim: 50x50, N=3, d=512, 40 envs, 1600 updates of 600 steps (115M agent-steps; GPU).",
    )


def _fast() -> Preset:
    # Half the cells at twice the cell size keeps the paper's 50 m x 50 m arena, so the channel geometry (and thus the
    # distance-driven dropouts of Eq. (1)) is the paper's; speed and safety distance scale with the cell. An ideal sweep
    # of the 625 cells needs 625 / (3 * 5 * 0.3) = 139 of the T = 300 steps (the paper's ratio is 556 of 1000).
    config = SwarmConfig(
        grid_width=25,
        grid_height=25,
        cell_size=2.0,
        v_max=0.6,
        vz_max=1.0,
        d_safe=4.0,
        num_obstacles=8,
        max_steps=300,
        initial_energy=30.0,
    )
    n_envs, n_steps = 16, 300
    return Preset(
        name="fast",
        config=config,
        n_envs=n_envs,
        total_timesteps=4_320_000,
        algo_kwargs=_algo_kwargs(
            n_steps=n_steps, chunk_length=25, batch_size=3000, latent_dim=64, hidden=128, learning_rate=3e-4, mappo=True
        ),
        baseline_timesteps=600_000,
        description="25x25 cells of 2 m (the paper's 50 m arena), T=300, d=64, 16 envs, 300 updates (~30 min on 2 cores).",
    )


def _coordination() -> Preset:
    # The paper's 50 m x 50 m arena in 20 x 20 cells of 2.5 m, 0.5 cells per step, every UAV launched from a common
    # 7.5 m corner square and a horizon that binds: an ideal sweep of the 400 cells needs 400 / (3 * 5 * 0.5) = 53 of
    # the T = 80 steps. Coordinated planners cover 97-100 %, the best message-free heuristic 72 % (benchmarks/
    # coordination_gap.py, table in docs/env.md). b_0 / kappa = T as in the paper: the horizon is the energy budget.
    # Training options chosen for time to a trained swarm (docs/results/coordination_time_to_coverage/, issue 21):
    # minibatches of 3,840 agent-steps (2 per epoch), 3 epochs and a learning rate of 1e-3 cost 1.77x fewer CPU
    # seconds per update than the first round's 1,920 / 5 / 3e-4 with the code of that day (interleaved in one run)
    # and reach the first round's final training coverage (95 %) in >= 1.02x fewer agent-steps, hence >= 1.71x sooner in
    # logged CPU seconds (6 seeds each, one machine; >= 1.73x on seeds 4-5, never run with this setting before),
    # with held-out coverage 97.11 % against 93.69 % (old code rerun) and 95.75 % (first round); 300 updates (2.3M
    # agent-steps) cost less CPU than the first round's 200. The second round's sweeps
    # (docs/results/coordination_round2*) trained with the earlier 6e-4 (their trial.json records it).
    horizon = 80
    config = SwarmConfig(
        grid_width=20,
        grid_height=20,
        cell_size=2.5,
        v_max=1.25,
        vz_max=1.0,
        d_safe=2.5,
        num_obstacles=5,
        max_steps=horizon,
        initial_energy=horizon * 0.1,
        start_region="corner",
        start_region_size=7.5,
    )
    n_envs, n_steps, updates = 16, 160, 300
    return Preset(
        name="coordination",
        config=config,
        n_envs=n_envs,
        total_timesteps=updates * n_steps * n_envs * config.n_agents,
        algo_kwargs=_algo_kwargs(
            n_steps=n_steps,
            chunk_length=20,
            batch_size=3840,
            latent_dim=64,
            hidden=128,
            learning_rate=1e-3,
            n_epochs=3,
            mappo=True,
        ),
        baseline_timesteps=updates * n_steps * n_envs * config.n_agents,
        eval_episodes=50,
        description="20x20 cells of 2.5 m, corner launch, T=80: message-free heuristics lose 28 points (~5 min, 1 thread).",
    )


def _random_corner() -> Preset:
    # `coordination` (arena, speeds, obstacles, training options) with five UAVs launched from one of the four corners,
    # drawn per episode (start_region="random_corner"): a convention fixed in training ("you take the left strip")
    # cannot split the map when the corner changes, so the UAVs must learn where the others are. The horizon binds:
    # T = 48 (b_0 / kappa = T), where an ideal sweep needs 400 / (5 * 5 * 0.5) = 32 steps; on this env the best
    # message-free scripted policy (random strips) loses 19.9 points to a coordinated planner (frontier with map sharing)
    # at T = 48, 21.4 at T = 40 and only 13.7 at T = 60 (benchmarks/coordination_gap.py, 100 episodes per cell,
    # docs/results/random_corner_preset_gap/). Outages are bursty (Gilbert-Elliott, p_f = 0.5, mean failure run 25
    # steps, half an episode): with four peers a UAV is cut off only when all four in-links are down, which at the
    # paper's Bernoulli p_f = 0.3 happens on 4 % of the planner's agent-steps in runs of 1.1 steps.
    # n_envs * n_steps * N = 16 * 96 * 5 = 7,680 agent-steps per update, as in `coordination` (16 * 160 * 3); 96 steps
    # are two episodes; chunks of 24 steps (4 per rollout); `coordination`'s minibatches (3,840 agent-steps), 3 epochs
    # and 300 updates, with the learning rate of 6e-4 its results were measured with (docs/results/random_corner_round2;
    # `coordination`'s 1e-3 was chosen on `coordination` alone).
    horizon = 48
    config = _coordination().config.replace(
        n_agents=5,
        start_region="random_corner",
        max_steps=horizon,
        initial_energy=horizon * 0.1,
        p_fail=0.5,
        outage_model="gilbert_elliott",
        mean_outage_steps=25.0,
    )
    coordination = _coordination()
    n_envs, n_steps, updates = coordination.n_envs, 96, coordination.updates
    return Preset(
        name="random_corner",
        config=config,
        n_envs=n_envs,
        total_timesteps=updates * n_steps * n_envs * config.n_agents,
        algo_kwargs={**coordination.algo_kwargs, "n_steps": n_steps, "chunk_length": 24, "learning_rate": 6e-4},
        baseline_timesteps=updates * n_steps * n_envs * config.n_agents,
        eval_episodes=50,
        description="coordination with N=5, a launch corner drawn per episode, T=48, bursty outages (p_f 0.5, mean 25).",
    )


def _demo() -> Preset:
    # A tiny `coordination`: 12 x 12 cells of 2.5 m, three UAVs from a common 7.5 m corner square, 0.5 cells per step,
    # T = 30 = b_0 / kappa where an ideal sweep needs 144 / (3 * 5 * 0.5) = 19 steps. Measured (examples/demo.py's
    # question, one training seed, 90k agent-steps, 30 held-out episodes, sampled actions): cutting every link costs
    # the trained swarm 3 points, and the same learner trained without links covers 7 points less; on the previous
    # demo task (12 x 12 cells of 1 m, N = 2, uniform starts) cutting the links cost nothing.
    config = SwarmConfig(
        n_agents=3,
        grid_width=12,
        grid_height=12,
        cell_size=2.5,
        v_max=1.25,
        vz_max=1.0,
        d_safe=2.5,
        num_obstacles=3,
        max_steps=30,
        initial_energy=3.0,
        start_region="corner",
        start_region_size=7.5,
    )
    return Preset(
        name="demo",
        config=config,
        n_envs=8,
        total_timesteps=90_000,
        algo_kwargs=_algo_kwargs(
            n_steps=40, chunk_length=10, batch_size=160, latent_dim=32, hidden=64, learning_rate=3e-4, mappo=True
        ),
        baseline_timesteps=20_000,
        eval_episodes=10,
        description="12x12 cells of 2.5 m, N=3, corner launch, T=30, d=32: a tiny coordination task (about a minute).",
    )


def _smoke() -> Preset:
    config = SwarmConfig(n_agents=3, grid_width=10, grid_height=10, max_steps=20, num_obstacles=4)
    return Preset(
        name="smoke",
        config=config,
        n_envs=2,
        total_timesteps=2 * 20 * 2 * 3,
        algo_kwargs=_algo_kwargs(n_steps=20, chunk_length=5, batch_size=30, latent_dim=8, hidden=16, n_epochs=1, mappo=True),
        baseline_timesteps=2 * 3 * 128,
        eval_episodes=2,
        description="Seconds: checks the whole pipeline runs; results mean nothing.",
    )


PRESETS: dict[str, Preset] = {
    preset.name: preset for preset in (_paper(), _fast(), _coordination(), _random_corner(), _demo(), _smoke())
}


def get_preset(name: str) -> Preset:
    """The preset called ``name`` (one of ``PRESETS``)."""
    try:
        return PRESETS[name]
    except KeyError:
        raise ValueError(f"Unknown preset {name!r}; choose one of {sorted(PRESETS)}") from None
