"""UAVs as processes: the simulator in this process, each UAV in its own (:mod:`sb3_latentswarm.agent.uav_process`),
connected by UDP on 127.0.0.1 (:mod:`sb3_latentswarm.agent.wire`).

Each step the :class:`Simulator` draws the links with the env's link model (the core's), sends every UAV its own
observation and the messages z_{t-1}^j of the peers whose links delivered (under delayed links, each arrival as its
sender broadcast it, z_{t-1-a}^j, with its age a), and waits for the replies (action a_t and
message z_t) until the step's deadline. A reply that misses the deadline is lost, its action and its message both: the
UAV hovers (zero command) that step and its peers receive nothing from it next step. A UAV that missed ``lost_after``
deadlines in a row is *lost*: the simulator stops waiting for it (it still sends it its datagrams and takes its reply
if one arrives in time). With no deadline misses an episode equals the one :class:`InProcessSwarm` flies with the same
nodes in this process, exactly (``tests/test_deploy_processes.py``).
"""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, NamedTuple

import numpy as np

from sb3_latentswarm.agent.uav_process import UavNode
from sb3_latentswarm.agent.wire import MAX_DATAGRAM, Kind, Packet, Wire, WireSpec, bind_udp
from sb3_latentswarm.config import SwarmConfig
from sb3_latentswarm.envs.batched_core import SwarmBatch
from sb3_latentswarm.envs.observations import PROPRIO_DIM
from sb3_latentswarm.utils.checks import check_bool, check_float, check_int

__all__ = ["EpisodeRecord", "InProcessSwarm", "ProcessSwarm", "Reply", "Simulator", "StepInput"]

_PACKAGE_ROOT = Path(__file__).resolve().parents[2]  # the folder that holds sb3_latentswarm/


class StepInput(NamedTuple):
    """What the simulator sends UAV i at one step."""

    local_obs: np.ndarray
    """o_t^i, (o_dim,) int8."""
    proprio: np.ndarray
    """e_t^i, (e_dim,) float32."""
    senders: list[int]
    """The peers j whose links j -> i delivered and whose message arrived, ascending."""
    messages: np.ndarray
    """Their messages z_{t-1-a}^j as they were broadcast, (k, d) float32, in the order of ``senders``."""
    ages: np.ndarray | None = None
    """How many steps late each message is (a; 0 = on time), (k,) int, in the order of ``senders``; ``None``: all on
    time."""


class Reply(NamedTuple):
    """A UAV's answer to one step."""

    action: np.ndarray
    message: np.ndarray
    compute_s: float
    """The UAV's agent step, measured in its process (seconds)."""
    round_trip_s: float
    """From sending the UAV its datagram to receiving its reply, in the simulator (seconds; 0 in process)."""


class InProcessSwarm:
    """The reference transport: the same :class:`~sb3_latentswarm.agent.uav_process.UavNode` s called in this process
    (no sockets; nothing misses a deadline unless :meth:`kill` ed).

    :param agents: one per-UAV agent per UAV (e.g. :class:`~sb3_latentswarm.agent.OnnxSwarmAgent`)
    """

    def __init__(self, agents: list[Any]) -> None:
        self.nodes = [UavNode(agent, i) for i, agent in enumerate(agents)]
        self.spec = self.nodes[0].spec
        self.n_agents = len(self.nodes)
        self._dead: set[int] = set()

    def reset(self, episode: int, seed: int, deterministic: bool, expected: set[int], deadline: float
              ) -> dict[int, np.ndarray]:
        return {i: node.reset(seed, self.n_agents, deterministic) for i, node in enumerate(self.nodes) if i not in self._dead}

    def step(self, episode: int, step: int, inputs: list[StepInput], expected: set[int], deadline: float
             ) -> dict[int, Reply]:
        replies = {}
        for i, (node, x) in enumerate(zip(self.nodes, inputs)):
            if i not in self._dead:
                replies[i] = Reply(*node.step(step, x.local_obs, x.proprio, x.messages, x.ages), 0.0)
        return replies

    def kill(self, uav: int) -> None:
        self._dead.add(uav)


class ProcessSwarm:
    """N UAV processes (``python -m sb3_latentswarm.agent.uav_process``), each loading ``model`` on its own, and the
    simulator's UDP socket; a context manager whose exit stops every process (``STOP``, then terminate, then kill).

    :param model: an ``.onnx`` file from :func:`~sb3_latentswarm.agent.export_onnx`, or a saved ``LatentSwarmPPO``
    :param n_agents: N, one process each
    :param port: the simulator's UDP port on 127.0.0.1 (0: a free one, chosen by the OS)
    :param uav_port: UAV i binds ``uav_port + i`` (0: each a free one)
    :param startup_timeout: seconds for every process to load its model and say hello
    :param idle_timeout: a UAV process exits when the simulator has been silent this long
    :raise PortInUseError: when ``port`` is taken
    :raise ValueError: for an ``.onnx`` file of a model trained on an adapted env (formats 3 and 4), before any process
        starts (a saved adapted model is refused by each UAV process as it starts: the ``RuntimeError`` below)
    :raise RuntimeError: when a UAV process exits before it is ready (its error in the message, e.g. a taken port) or
        is not ready after ``startup_timeout``
    """

    def __init__(self, model: str | os.PathLike[str], n_agents: int, port: int = 0, uav_port: int = 0,
                 startup_timeout: float = 120.0, idle_timeout: float = 30.0) -> None:
        self.n_agents = check_int("n_agents", n_agents, low=1)
        check_int("port", port, 0, 65_535)
        check_int("uav_port", uav_port, 0, 65_535 - self.n_agents)
        if os.fspath(model).endswith(".onnx"):  # an adapted model's file is refused here, not by N processes after start
            from sb3_latentswarm.agent.onnx_runtime import OnnxSwarmAgent

            UavNode(OnnxSwarmAgent(model), 0)
        self.sock = bind_udp(port)
        self.port = int(self.sock.getsockname()[1])
        self.procs: list[subprocess.Popen[bytes]] = []
        self._logs: list[IO[str]] = []
        self._log_dir = tempfile.TemporaryDirectory(prefix="sb3-latentswarm-uavs-")
        self.addresses: list[tuple[str, int] | None] = [None] * self.n_agents
        self.spec = WireSpec(0, 0, 0, 0)
        try:
            self._launch(os.fspath(model), uav_port, idle_timeout)
            self._await_hellos(check_float("startup_timeout", startup_timeout, 0.0, low_open=True))
        except BaseException:
            self.close()
            raise
        self.wire = Wire(self.spec)

    # ------------------------------------------------------------------ the transport
    def reset(self, episode: int, seed: int, deterministic: bool, expected: set[int], deadline: float
              ) -> dict[int, np.ndarray]:
        sent = {i: self._send(Wire.reset(episode, i, seed, self.n_agents, deterministic), i) for i in range(self.n_agents)}
        replies = self._collect(Kind.READY, episode, 0, expected, deadline, sent)
        return {i: packet.messages for i, (packet, _) in replies.items() if packet.messages is not None}

    def step(self, episode: int, step: int, inputs: list[StepInput], expected: set[int], deadline: float
             ) -> dict[int, Reply]:
        sent = {i: self._send(self.wire.step(episode, step, i, *x), i) for i, x in enumerate(inputs)}
        replies = self._collect(Kind.ACTION, episode, step, expected, deadline, sent)
        return {i: Reply(packet.action, packet.messages, packet.compute_s, rtt)  # type: ignore[arg-type]
                for i, (packet, rtt) in replies.items()}

    def kill(self, uav: int) -> None:
        """SIGKILL UAV ``uav``'s process (a UAV lost mid-flight) and reap it."""
        self.procs[uav].kill()
        self.procs[uav].wait(timeout=30)

    @property
    def exit_codes(self) -> dict[int, int | None]:
        """Each process's exit status (``None`` while it runs; -9 when killed)."""
        return {i: proc.poll() for i, proc in enumerate(self.procs)}

    # ------------------------------------------------------------------ lifetime
    def __enter__(self) -> ProcessSwarm:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def close(self) -> None:
        """Stop every UAV process (``STOP``, or terminate one that never said hello; terminate after 5 s; kill after 5
        more) and close the socket."""
        for i, proc in enumerate(self.procs):
            address = self.addresses[i]
            if address is None:  # still loading, or failed: it has no socket to read STOP from
                proc.terminate()
            else:
                with contextlib.suppress(OSError):
                    self.sock.sendto(Wire.stop(i), address)
        for proc in self.procs:
            try:
                proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                proc.terminate()
                try:
                    proc.wait(timeout=5)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()
        for log in self._logs:
            log.close()
        self._logs = []
        self.sock.close()
        self._log_dir.cleanup()

    def _launch(self, model: str, uav_port: int, idle_timeout: float) -> None:
        env = dict(os.environ)  # the children import this copy of the package
        env["PYTHONPATH"] = os.pathsep.join(filter(None, (str(_PACKAGE_ROOT), env.get("PYTHONPATH"))))
        for i in range(self.n_agents):
            log = open(Path(self._log_dir.name) / f"uav{i}.log", "w+")  # noqa: SIM115 - closed in close()
            self._logs.append(log)
            command = [sys.executable, "-m", "sb3_latentswarm.agent.uav_process", "--index", str(i), "--sim-port",
                       str(self.port), "--model", model, "--port", str(uav_port + i if uav_port else 0),
                       "--idle-timeout", str(idle_timeout)]
            self.procs.append(subprocess.Popen(command, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=log,
                                               env=env))

    def _await_hellos(self, startup_timeout: float) -> None:
        hello_wire = Wire(self.spec)  # HELLO's body does not depend on the sizes
        specs: dict[int, WireSpec] = {}
        end = time.monotonic() + startup_timeout
        self.sock.settimeout(0.25)
        while len(specs) < self.n_agents:
            try:
                data, address = self.sock.recvfrom(MAX_DATAGRAM)
            except TimeoutError:
                for i, proc in enumerate(self.procs):
                    if i not in specs and proc.poll() is not None:
                        raise RuntimeError(f"UAV {i}'s process exited with status {proc.returncode} before it was "
                                           f"ready: {self._log_tail(i)}") from None
                if time.monotonic() > end:
                    missing = sorted(set(range(self.n_agents)) - set(specs))
                    raise RuntimeError(f"UAV processes {missing} not ready after {startup_timeout:g} s") from None
                continue
            packet = hello_wire.decode(data)
            if packet is None or packet.kind != Kind.HELLO or not 0 <= packet.uav < self.n_agents:
                continue
            if packet.pid != self.procs[packet.uav].pid or packet.spec is None:
                continue
            specs[packet.uav] = packet.spec
            self.addresses[packet.uav] = address
        if len(set(specs.values())) != 1:
            raise RuntimeError(f"the UAV processes loaded models of different sizes: {specs}")
        self.spec = specs[0]

    def _log_tail(self, uav: int) -> str:
        log = self._logs[uav]
        log.flush()
        log.seek(0)
        lines = log.read().strip().splitlines()
        return " | ".join(lines[-5:]) or "(no output)"

    def _send(self, data: bytes, uav: int) -> float:
        address = self.addresses[uav]
        assert address is not None  # every UAV said hello
        sent = time.perf_counter()
        self.sock.sendto(data, address)
        return sent

    def _collect(self, kind: int, episode: int, step: int, expected: set[int], deadline: float,
                 sent: dict[int, float]) -> dict[int, tuple[Packet, float]]:
        """The replies of ``kind`` to (episode, step) that arrive before the deadline, with their round trips; returns
        early once every UAV in ``expected`` has answered. Stale and foreign datagrams are dropped."""
        replies: dict[int, tuple[Packet, float]] = {}
        waiting = set(expected)
        end = time.monotonic() + deadline
        while waiting:
            remaining = end - time.monotonic()
            if remaining <= 0:
                break
            self.sock.settimeout(remaining)
            try:
                data, address = self.sock.recvfrom(MAX_DATAGRAM)
            except TimeoutError:
                break
            packet = self.wire.decode(data)
            if packet is None or (packet.kind, packet.episode, packet.step) != (kind, episode, step):
                continue
            uav = packet.uav
            if not 0 <= uav < self.n_agents or address != self.addresses[uav] or uav in replies:
                continue
            replies[uav] = (packet, time.perf_counter() - sent[uav])
            waiting.discard(uav)
        return replies


@dataclass
class EpisodeRecord:
    """One episode flown by a :class:`Simulator` (T steps, N UAVs)."""

    seed: int
    summary: dict[str, Any]
    """The core's swarm summary (``coverage`` in [0, 1], ``collisions``, ``dropout_rate`` of the link model, ...) and
    ``seed``, ``deadline_misses`` (per UAV), ``lost`` ({UAV: the step its last run of misses began}, for the UAVs lost
    at the end), ``killed`` ({UAV: step}), ``relay_dropout_rate`` (the share of UAV-steps that received no message:
    the link model's dropouts and the lost senders')."""
    actions: np.ndarray
    """(T, N, action_dim) float32, the commands applied (zero: a hovering UAV that missed the deadline)."""
    links: np.ndarray
    """(T, N, N) bool, the link model's draw: [t, i, j] = the link j -> i was up at step t."""
    delivered: np.ndarray
    """(T, N, N) bool, the messages relayed: the link was up and j's message had arrived."""
    missed: np.ndarray
    """(T, N) bool, no reply before the deadline."""
    compute_s: np.ndarray
    """(T, N), each UAV's agent step as measured in its process (NaN: missed)."""
    round_trip_s: np.ndarray
    """(T, N), datagram out to reply in, per UAV (NaN: missed)."""
    step_s: np.ndarray
    """(T,), the simulator's whole exchange of one step (all datagrams out, all replies in)."""


class Simulator:
    """Flies episodes of one swarm through a transport (:class:`ProcessSwarm` or :class:`InProcessSwarm`), with the
    env's own core (:class:`~sb3_latentswarm.envs.batched_core.SwarmBatch`) and link model.

    :param swarm: the transport
    :param config: the swarm's configuration (the model's training config, e.g. ``model.swarm_config``)
    :param deadline: seconds each step waits for the replies (and each reset for the ``READY`` s)
    :param lost_after: a UAV that missed this many deadlines in a row is lost (not waited for any more)
    :raise ValueError: when the transport's model does not fit ``config`` (sizes; a delay-aware model needs the
        config's delay, ``message_delay`` > 0, and the expiry ``message_expiry`` it was trained with)

    Under delayed links (``config.message_delay`` > 0) the simulator keeps the messages of the last E + 1 steps and
    relays each arrival as its sender broadcast it, with its age (a message whose sender missed that step's deadline
    never arrives).
    """

    def __init__(self, swarm: InProcessSwarm | ProcessSwarm, config: SwarmConfig, deadline: float = 1.0,
                 lost_after: int = 3) -> None:
        self.swarm = swarm
        self.config = config
        self.deadline = check_float("deadline", deadline, 0.0, low_open=True)
        self.lost_after = check_int("lost_after", lost_after, low=1)
        spec, n = swarm.spec, config.n_agents
        o_dim = config.footprint_width**2
        if (spec.local_obs_size, spec.proprio_dim, swarm.n_agents) != (o_dim, PROPRIO_DIM, n):
            raise ValueError(
                f"the UAVs' model takes local_obs of {spec.local_obs_size} cells and proprio of {spec.proprio_dim} "
                f"floats for {swarm.n_agents} UAVs; the config has {o_dim}, {PROPRIO_DIM} and n_agents={n}"
            )
        if spec.delay_aware and (config.message_delay == 0 or spec.message_expiry != config.message_expiry):
            raise ValueError(
                f"the UAVs' model is delay-aware (delay_aware=True, expiry E = {spec.message_expiry}): fly it with the "
                f"delayed links it was trained with (message_delay > 0, message_expiry = {spec.message_expiry}); the "
                f"config has message_delay={config.message_delay}, message_expiry={config.message_expiry}"
            )
        self.core = SwarmBatch(config, 1)
        self.n_ages = config.message_expiry + 1 if config.message_delay > 0 else 1  # messages kept: E + 1 steps
        self.missed_in_a_row = np.zeros(n, dtype=np.int64)  # kept across episodes: a dead UAV stays lost
        self._episode = 0

    def fly(self, seed: int, deterministic: bool = False, kill_at: tuple[int, int] | None = None) -> EpisodeRecord:
        """One episode with env seed ``seed`` (and, sampled, the action noise of ``seed``: ``evaluate``'s episode).

        :param deterministic: every UAV takes its mean action
        :param kill_at: ``(uav, step)``: kill that UAV's process just before that step (a UAV lost mid-flight)
        """
        seed = check_int("seed", seed, low=0)
        check_bool("deterministic", deterministic)
        core, swarm, n, d = self.core, self.swarm, self.config.n_agents, self.swarm.spec.message_dim
        if kill_at is not None:
            kill_at = (check_int("kill_at[0] (the UAV)", kill_at[0], 0, n - 1),
                       check_int("kill_at[1] (the step)", kill_at[1], 0))
        episode = self._episode
        self._episode += 1
        core.reset(seeds=[seed])
        waited = {i for i in range(n) if self.missed_in_a_row[i] < self.lost_after}
        ready = swarm.reset(episode, seed, deterministic, waited, self.deadline)
        # sent[a][j]: what j broadcast a steps before the freshest message, z_{t-1-a}^j (None: not received)
        sent: list[list[np.ndarray | None]] = [[ready.get(i) for i in range(n)]]
        sent += [[None] * n for _ in range(self.n_ages - 1)]
        run_start = {i: 0 for i in range(n) if self.missed_in_a_row[i] > 0}
        killed: dict[int, int] = {}
        rows: list[tuple[np.ndarray, ...]] = []
        t = 0
        while True:
            if kill_at is not None and kill_at[1] == t:
                swarm.kill(kill_at[0])
                killed[kill_at[0]] = t
            links = core.link_rows[0] > 0  # (N, N): [i, j] = j -> i delivers this step
            ages = np.zeros((n, n), np.int64) if core.link_ages is None else core.link_ages[0].astype(np.int64)
            arrived = np.array([[m is not None for m in by_age] for by_age in sent])  # (E + 1, N)
            delivered = links & arrived[ages, np.arange(n)[None, :]]
            inputs = []
            for i in range(n):
                senders = np.flatnonzero(delivered[i]).tolist()
                stacked = (np.stack([sent[ages[i, j]][j] for j in senders]) if senders
                           else np.zeros((0, d), np.float32))
                inputs.append(StepInput(core.local_obs[0, i], core.proprio[0, i], senders, stacked, ages[i, senders]))
            waited = {i for i in range(n) if self.missed_in_a_row[i] < self.lost_after}
            start = time.perf_counter()
            replies = swarm.step(episode, t, inputs, waited, self.deadline)
            step_s = time.perf_counter() - start
            actions = np.zeros((n, swarm.spec.action_dim), dtype=np.float32)  # hover: no reply, no command
            compute, round_trip = np.full(n, np.nan), np.full(n, np.nan)
            messages: list[np.ndarray | None] = [None] * n
            for i in range(n):
                reply = replies.get(i)
                if reply is None:
                    run_start.setdefault(i, t)
                    self.missed_in_a_row[i] += 1
                    continue
                run_start.pop(i, None)
                self.missed_in_a_row[i] = 0
                actions[i], messages[i] = reply.action, np.array(reply.message, dtype=np.float32)
                compute[i], round_trip[i] = reply.compute_s, reply.round_trip_s
            sent = [messages, *sent[:-1]]
            rows.append((actions, links, delivered, np.isnan(compute), compute, round_trip, np.float64(step_s)))
            _, terminated, truncated = core.step(core.check_actions(actions.reshape(1, n, -1)))
            t += 1
            if terminated[0] or truncated[0]:
                break
        columns = [np.stack(column) for column in zip(*rows)]
        lost = {i: s for i, s in sorted(run_start.items()) if self.missed_in_a_row[i] >= self.lost_after}
        summary = core.swarm_summary(0)
        summary.update(
            seed=seed,
            deadline_misses={i: int(columns[3][:, i].sum()) for i in range(n)},
            lost=lost,
            killed=killed,
            relay_dropout_rate=float((columns[2].sum(axis=2) == 0).mean()),
        )
        return EpisodeRecord(seed, summary, *columns)
