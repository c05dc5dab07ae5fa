"""ONNX export of a policy trained on an adapted PettingZoo env (formats 3 and 4, ``agent/export.py``): the ONNX agents
fly the torch agents' episodes on MPE2's simple_spread (p_t from the observation's ``position``) and on the docs'
custom env without positions (a 0-wide ``proprio``, no position input), delay-aware too, and refuse what the torch
agent refuses. Tolerance: ONNX_ATOL of ``tests/test_agent.py`` (the export's own check, 1e-5)."""

import functools

import numpy as np
import pytest
import torch as th

pytest.importorskip("onnxruntime")

from test_agent import ONNX_ATOL, tiny_model  # noqa: E402
from test_parallel_adapter import (  # noqa: E402
    LINK_SPECS,
    SMALL_POLICY,
    Rendezvous,
    rendezvous_positions,
    simple_spread,
    small_model,
)

from sb3_latentswarm.agent import LatentSwarmAgent, OnnxSwarmAgent, export_onnx  # noqa: E402
from sb3_latentswarm.agent.export import INPUT_NAMES  # noqa: E402
from sb3_latentswarm.envs import LinkSpec, make_adapted_vec_env  # noqa: E402
from sb3_latentswarm.envs.mpe import mpe_positions  # noqa: E402

DELAYED_SPEC = LinkSpec(link_model="outage", p_fail=0.3, message_delay=1, message_delay_model="uniform",
                        message_expiry=2)
ENVS = {  # name -> (the vec env of one copy by seed, its episode length, policy kwargs)
    "simple_spread_positions": (functools.partial(make_adapted_vec_env, simple_spread, link_model=LINK_SPECS[
        "gilbert_elliott"], position_fn=mpe_positions), 10, {}),
    "rendezvous_no_positions": (functools.partial(make_adapted_vec_env, Rendezvous, link_model=LINK_SPECS["bernoulli"]),
                                20, {}),
    "rendezvous_delay_aware": (functools.partial(make_adapted_vec_env, Rendezvous, link_model=DELAYED_SPEC,
                                                 position_fn=rendezvous_positions), 20, {"delay_aware": True}),
}


def trained_model(name):
    """A model of ``ENVS[name]`` trained for 4 updates (2 copies), its actor's mean then given actions that differ
    between agents (an untrained actor's mean is ~0: gain 0.01)."""
    make, episode, policy_kwargs = ENVS[name]
    model = small_model(make(2, seed=0), episode=episode, policy_kwargs={**SMALL_POLICY, **policy_kwargs})
    model.learn(4 * episode * 6, log_interval=10**6)
    with th.no_grad():
        model.policy.action_mean.weight.copy_(th.randn(model.policy.action_mean.weight.shape,
                                                       generator=th.Generator().manual_seed(1)))
    return model


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """``exported(name)``: (model, path of its exported file, the export's check) of ``ENVS[name]``, built once."""
    built = {}

    def get(name):
        if name not in built:
            model = trained_model(name)
            path = tmp_path_factory.mktemp("adapted") / f"{name}.onnx"
            built[name] = model, path, export_onnx(model, path)
        return built[name]

    return get


def fly_pair(model, path, env, seed):
    """One sampled episode of ``env`` (one copy) stepped twice in lockstep: N OnnxSwarmAgents and N torch agents, each
    group with its own messages routed by the link rows (under delay, each arrival as its sender broadcast it, with
    its age for a delay-aware policy), the same noise; the env takes the torch agents' actions. Returns the largest
    difference of actions and messages, the steps, and how many agent-steps had no message."""
    n, d = env.get_attr("n_agents", indices=0)[0], model.policy.message_dim
    groups = ([OnnxSwarmAgent(path) for _ in range(n)], [LatentSwarmAgent(model) for _ in range(n)])
    for agent in (*groups[0], *groups[1]):
        agent.reset()
    env.seed(seed)
    obs = env.reset()
    rng = np.random.default_rng(seed)
    histories = ([], [])  # histories[g][-1 - a][j]: what UAV j of group g broadcast a steps before z_{t-1}
    largest, steps, dropped = 0.0, 0, 0
    while True:
        noise = rng.standard_normal((n, model.policy.action_dim)).astype(np.float32)
        ages = obs["link_age"].astype(int) if "link_age" in obs else np.zeros((n, n), dtype=int)
        actions = []
        for group, history in zip(groups, histories):
            history.append(np.stack([agent.message() for agent in group]))
            step = []
            for i, agent in enumerate(group):
                senders = np.flatnonzero(obs["link_row"][i] > 0)
                messages = np.array([history[-1 - a][j] for j, a in zip(senders, ages[i, senders])])
                step.append(agent.step({key: obs[key][i] for key in obs}, messages.reshape(len(senders), d),
                                       noise=noise[i], message_ages=ages[i, senders] if agent.delay_aware else None))
            actions.append(np.stack(step))
        largest = max(largest, float(np.abs(actions[0] - actions[1]).max()),
                      float(np.abs(histories[0][-1] - histories[1][-1]).max()))
        dropped += int((obs["link_row"].sum(-1) == 0).sum())
        steps += 1
        obs, _, dones, _ = env.step(actions[1])
        if dones.any():
            assert dones.all()
            return largest, steps, dropped


@pytest.mark.parametrize("name", list(ENVS))
def test_the_onnx_agents_fly_the_torch_agents_episode(exported, name):
    model, path, check = exported(name)
    assert check.max_abs_error <= check.tolerance == ONNX_ATOL
    make, episode, _ = ENVS[name]
    largest, steps, dropped = fly_pair(model, path, make(1, seed=5), seed=5)
    assert steps == episode and dropped > 0  # (the predictor's path ran too)
    assert largest < ONNX_ATOL


@pytest.mark.parametrize("name", list(ENVS))
def test_the_file_records_the_layout_and_takes_its_inputs(exported, name):
    model, path, _ = exported(name)
    agent = OnnxSwarmAgent(path)
    torch_agent = LatentSwarmAgent(model)
    assert agent.spec == torch_agent.spec  # the same sizes, position_key and position_dims, so the same checks
    aware = name == "rendezvous_delay_aware"
    assert agent.metadata["format"] == (4 if aware else 3) and agent.delay_aware == aware
    inputs = {i.name: i.shape for i in agent.session.get_inputs()}
    assert ("message_age" in inputs) == aware
    positions = name != "rendezvous_no_positions"
    assert agent.metadata["position_key"] == ("position" if positions else None)
    assert agent.metadata["position_dims"] == model.policy.position_dims == (3 if positions else 0)
    if positions:
        assert inputs["position"] == ["batch", 3]
        assert list(inputs).index("position") == list(inputs).index("proprio") + 1
    else:
        assert "position" not in inputs
    assert inputs["proprio"] == ["batch", model.policy.proprio_dim] and model.policy.proprio_dim == 0  # (B, 0)


@pytest.mark.parametrize("name", ["simple_spread_positions", "rendezvous_delay_aware"])
def test_the_position_is_read_and_checked_as_by_the_torch_agent(exported, name):
    model, path, _ = exported(name)
    agents = [OnnxSwarmAgent(path), LatentSwarmAgent(model)]
    space = model.observation_space
    obs = {key: np.zeros(space[key].shape, np.float32) for key in ("local_obs", "proprio", "position")}
    d = agents[0].message_dim
    after = []
    for position in (np.zeros(3), np.array([0.5, -0.5, 0.0])):  # p_t moves the map state mu, so the message
        messages = []
        for agent in agents:
            agent.reset()
            agent.step({**obs, "position": position}, np.ones((1, d)), deterministic=True)
            messages.append(agent.message())
        np.testing.assert_allclose(messages[0], messages[1], rtol=0, atol=ONNX_ATOL)
        after.append(messages[0])
    assert np.abs(after[0] - after[1]).max() > 100 * ONNX_ATOL
    cases = [(r"observation\['position'\] must have shape \(3,\), got \(2,\)", {**obs, "position": np.zeros(2)}),
             (r"lacks the key\(s\) \['position'\]", {"local_obs": obs["local_obs"], "proprio": obs["proprio"]}),
             ("non-finite", {**obs, "position": np.array([0.0, np.nan, 0.0])})]
    for match, observation in cases:
        for agent in agents:
            before = agent.message()
            with pytest.raises(ValueError, match=match):
                agent.step(observation, np.ones((1, d)))
            np.testing.assert_array_equal(agent.message(), before)  # the state is unchanged


def test_a_swarm_env_file_keeps_format_1_and_its_metadata(tmp_path):
    path = tmp_path / "swarm.onnx"
    export_onnx(tiny_model(), path, n_check_steps=2)
    agent = OnnxSwarmAgent(path)
    assert [i.name for i in agent.session.get_inputs()] == list(INPUT_NAMES)
    assert agent.metadata["format"] == 1 and agent.spec.position_key == "proprio" and agent.spec.position_dims == 3
    assert set(agent.metadata) == {"format", "state_dims", "local_obs_shape", "proprio_dim", "message_dim",
                                   "action_dim", "action_low", "action_high", "message_substitute", "no_memory",
                                   "trained_autocast"}


def test_a_file_of_an_unknown_or_inconsistent_format_is_refused(exported, tmp_path):
    import json

    import onnx

    _, path, _ = exported("rendezvous_no_positions")
    graph = onnx.load(path)
    metadata = json.loads(next(p.value for p in graph.metadata_props if p.key == "sb3_latentswarm"))
    for change, match in (({"format": 5}, r"has export format 5; this runtime reads \[1, 2, 3, 4\]"),
                          ({"format": 1}, r"format 1 does not match delay_aware=False and position_key=None"),
                          ({"position_key": "proprio"}, "format 3 does not match"),
                          ({"position_key": "elsewhere"}, "format 3 does not match")):
        onnx.helper.set_model_props(graph, {"sb3_latentswarm": json.dumps({**metadata, **change})})
        changed = tmp_path / "changed.onnx"
        onnx.save(graph, changed)
        with pytest.raises(ValueError, match=match):
            OnnxSwarmAgent(changed)


@pytest.mark.parametrize("name", ["simple_spread_positions", "rendezvous_no_positions"])
def test_the_uav_process_simulator_refuses_an_adapted_model(exported, name):
    """The simulator's wire carries the swarm env's ``local_obs`` and ``proprio``: an adapted model's agent (ONNX or
    torch) is refused when its node is built, before any episode, not at its first step."""
    from sb3_latentswarm.agent.processes import InProcessSwarm

    model, path, _ = exported(name)
    for agent in (OnnxSwarmAgent(path), LatentSwarmAgent(model)):
        with pytest.raises(ValueError, match="adapted env"):
            InProcessSwarm([agent])


def test_a_deployment_mistake_is_named_before_any_work(exported, tmp_path):
    """A saved model handed to the ONNX runtime, a 2-D position, an export into a missing folder, and an adapted file
    handed to the UAV processes: each a clear error before any work (no process started, no file written)."""
    from sb3_latentswarm.agent.processes import ProcessSwarm

    model, path, _ = exported("simple_spread_positions")
    model.save(tmp_path / "saved.zip")
    with pytest.raises(ValueError, match="is a zip file .* LatentSwarmAgent"):
        OnnxSwarmAgent(tmp_path / "saved.zip")
    agent = OnnxSwarmAgent(path)
    agent.reset(seed=0)
    space = model.observation_space
    obs = {key: np.zeros(space[key].shape, np.float32) for key in ("local_obs", "proprio")}
    with pytest.raises(ValueError, match=r"got \(2,\) \(2-D positions are padded with z = 0"):
        agent.step({**obs, "position": np.zeros(2)}, np.zeros((0, agent.message_dim)))
    with pytest.raises(FileNotFoundError, match="missing.*its folder does not exist"):
        export_onnx(model, tmp_path / "missing" / "x.onnx")
    assert not (tmp_path / "missing").exists()
    with pytest.raises(ValueError, match="adapted env"):
        ProcessSwarm(path, 2)


def test_a_uav_process_given_an_adapted_model_exits_with_one_line(exported, capsys):
    from sb3_latentswarm.agent.uav_process import EXIT_BAD_MODEL, main

    _, path, _ = exported("rendezvous_no_positions")
    assert main(["--index", "0", "--sim-port", "9", "--model", str(path)]) == EXIT_BAD_MODEL
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "adapted env" in err
