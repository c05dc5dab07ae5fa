"""The datagrams between the simulator process and the UAV processes (UDP on 127.0.0.1; numpy and the standard
library only, so a UAV process never imports torch).

Every datagram starts with the header ``<4sBIIH``: magic ``b"LSW2"`` (version 2 added the message ages), kind,
episode, step, UAV index; the body follows in little-endian order:

==========  ==============  ===========================================================================================
kind        direction       body
==========  ==============  ===========================================================================================
``HELLO``   UAV -> sim      pid (u32), o_dim, e_dim, d, action_dim (u16 each), delay-aware (u8), E (u16): the UAV's
                            model has loaded (E: the largest message age it was built for, 0 without delay)
``RESET``   sim -> UAV      episode seed (u64), N (u16), deterministic (u8)
``READY``   UAV -> sim      z (d float32): the message after reset (zero)
``STEP``    sim -> UAV      o_t (o_dim int8), e_t (e_dim float32), k (u16), the k senders (u16), their k ages (u16,
                            steps late; 0 without delay), their k messages z_{t-1-a}^j (k x d float32, each as its
                            sender broadcast it): only the messages that arrived this step
``ACTION``  UAV -> sim      the step's compute time (float64 s), a_t (action_dim float32), z_t (d float32)
``STOP``    sim -> UAV      (none): the UAV process exits
==========  ==============  ===========================================================================================
"""

from __future__ import annotations

import errno
import socket
import struct
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

__all__ = ["HOST", "MAX_DATAGRAM", "Kind", "Packet", "PortInUseError", "Wire", "WireSpec", "bind_udp"]

HOST = "127.0.0.1"
"""The loopback interface: nothing here listens beyond this machine."""
MAX_DATAGRAM = 65_507
"""The largest UDP payload over IPv4."""
_MAGIC = b"LSW2"
_HEADER = struct.Struct("<4sBIIH")
_HELLO = struct.Struct("<IHHHHBH")
_RESET = struct.Struct("<QHB")
_COUNT = struct.Struct("<H")
_SECONDS = struct.Struct("<d")


class Kind:
    """The datagram kinds (the header's second field)."""

    HELLO, RESET, READY, STEP, ACTION, STOP = range(1, 7)


class PortInUseError(OSError):
    """A UDP port on 127.0.0.1 is taken by another socket."""


def bind_udp(port: int) -> socket.socket:
    """A UDP socket bound to ``127.0.0.1:port`` (0: a free port chosen by the OS).

    :raise PortInUseError: when another socket holds the port
    """
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.bind((HOST, int(port)))
    except OSError as error:
        sock.close()
        if error.errno == errno.EADDRINUSE:
            raise PortInUseError(
                errno.EADDRINUSE,
                f"UDP port {port} on {HOST} is taken by another socket: give another port, or 0 to let the OS choose "
                "a free one",
            ) from error
        raise
    return sock


@dataclass(frozen=True)
class WireSpec:
    """The sizes of one UAV's step on the wire (the model's; every UAV of a swarm has the same)."""

    local_obs_size: int
    """o_dim, the cells of ``local_obs`` (int8 readings: -1 unknown / outside, 0 free, 1 occupied)."""
    proprio_dim: int
    """e_dim, the floats of ``proprio``."""
    message_dim: int
    """d = d_mu + d_tau."""
    action_dim: int
    delay_aware: bool = False
    """Whether the UAV's policy reads message ages (``delay_aware=True``, an extension)."""
    message_expiry: int = 0
    """E, the largest message age (steps) the policy was built for; 0 without delayed links."""


class Packet(NamedTuple):
    """A decoded datagram; the fields a kind does not carry are ``None``."""

    kind: int
    episode: int
    step: int
    uav: int
    pid: int | None = None
    spec: WireSpec | None = None
    seed: int | None = None
    n_agents: int | None = None
    deterministic: bool | None = None
    local_obs: np.ndarray | None = None
    proprio: np.ndarray | None = None
    senders: np.ndarray | None = None
    ages: np.ndarray | None = None
    """(k,) uint16 for ``STEP``: how many steps late each message is."""
    messages: np.ndarray | None = None
    """(k, d) for ``STEP``; (d,) for ``READY`` and ``ACTION`` (the UAV's own message)."""
    action: np.ndarray | None = None
    compute_s: float | None = None


class Wire:
    """Encodes and decodes the datagrams of one swarm (:class:`WireSpec` sizes).

    :raise ValueError: (``step``) for a datagram over :data:`MAX_DATAGRAM` bytes
    """

    def __init__(self, spec: WireSpec) -> None:
        self.spec = spec

    @staticmethod
    def header(kind: int, episode: int, step: int, uav: int) -> bytes:
        return _HEADER.pack(_MAGIC, kind, episode, step, uav)

    @staticmethod
    def hello(uav: int, pid: int, spec: WireSpec) -> bytes:
        return Wire.header(Kind.HELLO, 0, 0, uav) + _HELLO.pack(
            pid, spec.local_obs_size, spec.proprio_dim, spec.message_dim, spec.action_dim, int(spec.delay_aware),
            spec.message_expiry,
        )

    @staticmethod
    def reset(episode: int, uav: int, seed: int, n_agents: int, deterministic: bool) -> bytes:
        return Wire.header(Kind.RESET, episode, 0, uav) + _RESET.pack(seed, n_agents, int(deterministic))

    @staticmethod
    def stop(uav: int) -> bytes:
        return Wire.header(Kind.STOP, 0, 0, uav)

    def ready(self, episode: int, uav: int, message: np.ndarray) -> bytes:
        return self.header(Kind.READY, episode, 0, uav) + self._floats(message, self.spec.message_dim)

    def step(self, episode: int, step: int, uav: int, local_obs: np.ndarray, proprio: np.ndarray, senders: list[int],
             messages: np.ndarray, ages: list[int] | np.ndarray | None = None) -> bytes:
        """``ages``: how many steps late each message is, in the order of ``senders`` (``None``: all on time)."""
        ages = np.zeros(len(senders), dtype="<u2") if ages is None else np.asarray(ages, dtype="<u2")
        if ages.shape != (len(senders),):
            raise ValueError(f"expected one age per sender ({len(senders)}), got shape {ages.shape}")
        data = b"".join((
            self.header(Kind.STEP, episode, step, uav),
            np.ascontiguousarray(local_obs, dtype=np.int8).reshape(-1).tobytes(),
            self._floats(proprio, self.spec.proprio_dim),
            _COUNT.pack(len(senders)),
            np.asarray(senders, dtype="<u2").tobytes(),
            ages.tobytes(),
            np.ascontiguousarray(messages, dtype="<f4").tobytes(),
        ))
        if len(data) > MAX_DATAGRAM:
            raise ValueError(
                f"a step datagram of {len(data)} bytes ({len(senders)} messages of d = {self.spec.message_dim} floats) "
                f"exceeds UDP's {MAX_DATAGRAM} bytes"
            )
        return data

    def action(self, episode: int, step: int, uav: int, compute_s: float, action: np.ndarray, message: np.ndarray) -> bytes:
        return b"".join((
            self.header(Kind.ACTION, episode, step, uav),
            _SECONDS.pack(compute_s),
            self._floats(action, self.spec.action_dim),
            self._floats(message, self.spec.message_dim),
        ))

    def decode(self, data: bytes) -> Packet | None:
        """The packet in ``data``, or ``None`` for a datagram that is not ours or has the wrong size."""
        try:
            return self._decode(data)
        except (struct.error, ValueError):
            return None

    def _decode(self, data: bytes) -> Packet | None:
        if len(data) < _HEADER.size:
            return None
        magic, kind, episode, step, uav = _HEADER.unpack_from(data)
        if magic != _MAGIC:
            return None
        body = memoryview(data)[_HEADER.size :]
        head = Packet(kind, episode, step, uav)
        spec = self.spec
        d = spec.message_dim
        if kind == Kind.HELLO:
            pid, o_dim, e_dim, d_msg, a_dim, delay_aware, expiry = _HELLO.unpack(body)
            return head._replace(pid=pid, spec=WireSpec(o_dim, e_dim, d_msg, a_dim, bool(delay_aware), expiry))
        if kind == Kind.RESET:
            seed, n_agents, deterministic = _RESET.unpack(body)
            return head._replace(seed=seed, n_agents=n_agents, deterministic=bool(deterministic))
        if kind == Kind.READY:
            return head._replace(messages=self._exact(body, d))
        if kind == Kind.STEP:
            o, e = spec.local_obs_size, spec.proprio_dim
            local_obs = np.frombuffer(body, np.int8, o)
            proprio = np.frombuffer(body, "<f4", e, o)
            offset = o + 4 * e
            (k,) = _COUNT.unpack_from(body, offset)
            senders = np.frombuffer(body, "<u2", k, offset + _COUNT.size)
            ages = np.frombuffer(body, "<u2", k, offset + _COUNT.size + 2 * k)
            offset += _COUNT.size + 4 * k
            messages = self._exact(body[offset:], k * d).reshape(k, d)
            return head._replace(local_obs=local_obs, proprio=proprio, senders=senders, ages=ages, messages=messages)
        if kind == Kind.ACTION:
            (compute_s,) = _SECONDS.unpack_from(body)
            rest = body[_SECONDS.size :]
            action = np.frombuffer(rest, "<f4", spec.action_dim)
            message = self._exact(rest[4 * spec.action_dim :], d)
            return head._replace(compute_s=compute_s, action=action, messages=message)
        if kind == Kind.STOP:
            return head
        return None

    @staticmethod
    def _floats(values: np.ndarray, size: int) -> bytes:
        array = np.ascontiguousarray(values, dtype="<f4").reshape(-1)
        if array.size != size:
            raise ValueError(f"expected {size} floats, got {array.size}")
        return array.tobytes()

    @staticmethod
    def _exact(body: memoryview, count: int) -> np.ndarray:
        """The ``count`` float32 that make up all of ``body``."""
        if len(body) != 4 * count:
            raise ValueError(f"expected {4 * count} bytes, got {len(body)}")
        return np.frombuffer(body, "<f4", count)
