"""One UAV as its own process: it loads its model on its own, binds a UDP socket on 127.0.0.1 and answers the
simulator's datagrams (:mod:`sb3_latentswarm.agent.wire`) until told to stop.

    python -m sb3_latentswarm.agent.uav_process --index 0 --sim-port 5555 --model uav.onnx

An ``.onnx`` file runs in :class:`~sb3_latentswarm.agent.OnnxSwarmAgent` (numpy and onnxruntime: this process never
imports torch); any other file is a saved ``LatentSwarmPPO`` stepped by :class:`~sb3_latentswarm.agent.LatentSwarmAgent`.
:func:`~sb3_latentswarm.agent.processes.launch_uavs` starts these processes; see ``docs/deploy.md``.
"""

from __future__ import annotations

import argparse
import os
import socket
import sys
import time
from typing import Any

import numpy as np

from sb3_latentswarm.agent.wire import HOST, MAX_DATAGRAM, Kind, PortInUseError, Wire, WireSpec, bind_udp
from sb3_latentswarm.utils.seeding import action_noise_rng

__all__ = ["EXIT_BAD_MODEL", "EXIT_BAD_PORT", "EXIT_IDLE", "EXIT_ORPHANED", "UavNode", "load_agent", "main", "serve"]

EXIT_BAD_PORT = 2
"""Exit status when the UAV's port is taken."""
EXIT_IDLE = 3
"""Exit status when the simulator was silent for ``--idle-timeout`` seconds."""
EXIT_ORPHANED = 4
"""Exit status when the process that started this one is gone."""
EXIT_BAD_MODEL = 5
"""Exit status when ``--model`` cannot be read or is refused (e.g. a model trained on an adapted env)."""


def load_agent(path: str) -> Any:
    """The per-UAV agent of the model at ``path``: an ``.onnx`` file (torch-free) or a saved ``LatentSwarmPPO``."""
    if path.endswith(".onnx"):
        from sb3_latentswarm.agent.onnx_runtime import OnnxSwarmAgent

        return OnnxSwarmAgent(path)
    from sb3_latentswarm.agent.agent import LatentSwarmAgent
    from sb3_latentswarm.latent_ppo import LatentSwarmPPO

    return LatentSwarmAgent(LatentSwarmPPO.load(path, device="cpu"))


class UavNode:
    """UAV ``index``'s side of the protocol without the transport: reset and step its agent, and draw its action noise
    as the evaluation runner does (:func:`~sb3_latentswarm.utils.seeding.action_noise_rng` of the episode seed, one
    ``(N, action_dim)`` draw per step, row ``index``), so a sampled episode is the one ``evaluate`` flies.

    A delay-aware agent (``delay_aware=True``) gets the message ages the simulator relays; any other agent gets the
    messages only (each as its sender broadcast it).

    :param agent: a :class:`~sb3_latentswarm.agent.LatentSwarmAgent` or :class:`~sb3_latentswarm.agent.OnnxSwarmAgent`
        of a model trained on the swarm env (the wire carries ``local_obs`` and ``proprio``, whose first entries are p_t)
    :raise ValueError: for an agent of a model trained on an adapted env (it reads p_t elsewhere, or none): step it
        with its own env's observations instead
    """

    def __init__(self, agent: Any, index: int) -> None:
        spec = agent.spec
        if spec.position_key != "proprio":
            raise ValueError(
                "the UAV process simulator flies the swarm env's layout (p_t in proprio); this agent's model was trained "
                f"on an adapted env (position_key={spec.position_key!r}): step LatentSwarmAgent / OnnxSwarmAgent with "
                "that env's observations"
            )
        self.agent = agent
        self.index = int(index)
        self.spec = WireSpec(int(np.prod(spec.local_obs_shape)), spec.proprio_dim, spec.message_dim, spec.action_dim,
                             bool(agent.delay_aware), int(agent.message_expiry))
        self._noise: np.random.Generator | None = None
        self._n_agents = 1
        self._drawn = 0  # steps whose noise has been drawn

    def reset(self, seed: int, n_agents: int, deterministic: bool) -> np.ndarray:
        """Start an episode; return the message z the UAV broadcasts before its first step (zero)."""
        self.agent.reset(seed=seed)
        self._noise = None if deterministic else action_noise_rng(seed)
        self._n_agents, self._drawn = int(n_agents), 0
        return self.agent.message()

    def step(self, step: int, local_obs: np.ndarray, proprio: np.ndarray, messages: np.ndarray,
             ages: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, float]:
        """Step ``step`` (0 after reset) with the messages that were relayed (and their ages in steps, ``None``: on
        time): the action, the next message and the agent step's compute time in seconds. Noise of steps this UAV
        never saw is drawn and dropped."""
        noise = None
        if self._noise is not None:
            while self._drawn <= step:
                noise = self._noise.standard_normal((self._n_agents, self.spec.action_dim)).astype(np.float32)[self.index]
                self._drawn += 1
        observation = {"local_obs": local_obs.reshape(self.agent.spec.local_obs_shape), "proprio": proprio}
        start = time.perf_counter()
        message_ages = ages if self.spec.delay_aware else None
        action = self.agent.step(observation, messages, deterministic=self._noise is None, noise=noise,
                                 message_ages=message_ages)
        compute_s = time.perf_counter() - start
        return action, self.agent.message(), compute_s


def serve(sock: socket.socket, node: UavNode, sim_port: int, idle_timeout: float, poll_s: float = 0.25) -> int:
    """Answer the simulator at ``127.0.0.1:sim_port`` until it says ``STOP`` (return 0), is silent for
    ``idle_timeout`` seconds (:data:`EXIT_IDLE`) or the parent process is gone (:data:`EXIT_ORPHANED`).

    ``HELLO`` is repeated every ``poll_s`` until the simulator's first datagram. A step whose inputs the agent refuses
    (e.g. a non-finite message) is reported on stderr and not answered: the simulator counts a deadline miss.
    """
    wire = Wire(node.spec)
    simulator = (HOST, int(sim_port))
    parent = os.getppid()
    hello = wire.hello(node.index, os.getpid(), node.spec)
    sock.settimeout(poll_s)
    sock.sendto(hello, simulator)
    heard, last_heard, episode = False, time.monotonic(), -1
    while True:
        try:
            data, address = sock.recvfrom(MAX_DATAGRAM)
        except TimeoutError:
            if time.monotonic() - last_heard > idle_timeout:
                return EXIT_IDLE
            if os.getppid() != parent:
                return EXIT_ORPHANED
            if not heard:
                sock.sendto(hello, simulator)
            continue
        packet = wire.decode(data)
        if address != simulator or packet is None or packet.uav != node.index:
            continue
        heard, last_heard = True, time.monotonic()
        if packet.kind == Kind.STOP:
            return 0
        if packet.kind == Kind.RESET:
            assert packet.seed is not None and packet.n_agents is not None and packet.deterministic is not None
            episode = packet.episode
            message = node.reset(packet.seed, packet.n_agents, packet.deterministic)
            sock.sendto(wire.ready(episode, node.index, message), simulator)
        elif packet.kind == Kind.STEP and packet.episode == episode:
            assert packet.local_obs is not None and packet.proprio is not None and packet.messages is not None
            try:
                action, message, compute_s = node.step(packet.step, packet.local_obs, packet.proprio, packet.messages,
                                                       packet.ages)
            except ValueError as error:
                print(f"UAV {node.index}: step {packet.step} refused: {error}", file=sys.stderr, flush=True)
                continue
            sock.sendto(wire.action(episode, packet.step, node.index, compute_s, action, message), simulator)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--index", type=int, required=True, help="this UAV's index i in the swarm (0 .. N - 1)")
    parser.add_argument("--sim-port", type=int, required=True, help="the simulator's UDP port on 127.0.0.1")
    parser.add_argument("--model", required=True, help="an .onnx file from export_onnx, or a saved LatentSwarmPPO")
    parser.add_argument("--port", type=int, default=0, help="this UAV's UDP port on 127.0.0.1 (0: a free one)")
    parser.add_argument("--idle-timeout", type=float, default=30.0,
                        help="exit after this many seconds without a datagram from the simulator")
    args = parser.parse_args(argv)
    try:
        sock = bind_udp(args.port)
    except PortInUseError as error:
        print(f"UAV {args.index}: {error.strerror}", file=sys.stderr, flush=True)
        return EXIT_BAD_PORT
    with sock:
        try:
            node = UavNode(load_agent(args.model), args.index)
        except (OSError, TypeError, ValueError) as error:
            print(f"UAV {args.index}: {args.model}: {error}", file=sys.stderr, flush=True)
            return EXIT_BAD_MODEL
        return serve(sock, node, args.sim_port, args.idle_timeout)


if __name__ == "__main__":
    sys.exit(main())
