"""``OnnxSwarmAgent``: one UAV's policy from a file written by :func:`~sb3_latentswarm.agent.export_onnx`, run with
onnxruntime and numpy only (this module never imports torch), with the API of
:class:`~sb3_latentswarm.agent.LatentSwarmAgent`."""

from __future__ import annotations

import json
import os
from typing import Any

import numpy as np

from sb3_latentswarm.agent.inputs import AgentSpec, AgentStepInfo, check_step, pooled_message_age

__all__ = ["FORMATS", "OnnxSwarmAgent", "onnx_io_names"]

_METADATA_KEY = "sb3_latentswarm"  # export.METADATA_KEY (export imports torch)
FORMATS = {(False, False): 1, (False, True): 2, (True, False): 3, (True, True): 4}
"""The export format of a file, by (adapted layout, delay-aware): 1, the paper's step on the swarm env's layout (p_t
is the first entries of ``proprio``); 2, format 1 with the age state ``prev_message_age`` and the age input
``message_age``; 3, the step of a policy trained on an adapted env (``docs/own_env.md``): p_t from the input
``position`` where the env has positions, none otherwise, as the metadata's ``position_key`` says; 4, format 3 with
the age state and input."""
_STATE_NAMES = ("map_state", "task_state", "memory_state", "prev_local_obs", "prev_message", "held_message")


def onnx_io_names(delay_aware: bool, position: bool = False) -> tuple[tuple[str, ...], tuple[str, ...], tuple[str, ...]]:
    """``(state, input, output)`` names of an exported step (``export_onnx``'s table); a delay-aware step adds the state
    ``prev_message_age`` (alpha_{t-1}, (B, 1)) and the input ``message_age`` (alpha_t, (B, 1), after
    ``message_count``); ``position``: the step of an adapted layout that reads p_t from the observation's ``position``
    key adds the input ``position`` ((B, position_dims), after ``proprio``; formats 3 and 4)."""
    states = (*_STATE_NAMES, "prev_message_age") if delay_aware else _STATE_NAMES
    age = ("message_age",) if delay_aware else ()
    inputs = (*states, "local_obs", "proprio", *(("position",) if position else ()), "message_mean", "message_count",
              *age, "noise")
    outputs = ("action", *(f"next_{name}" for name in states), "message", "predicted_message")
    return states, inputs, outputs


class OnnxSwarmAgent:
    """One UAV of a trained swarm, stepped with onnxruntime: :meth:`reset`, :meth:`message` and :meth:`step` as
    :class:`~sb3_latentswarm.agent.LatentSwarmAgent` (the same checks and errors); the latent state is kept here in
    numpy and passed through the graph at each step.

    :param path: an ``.onnx`` file written by :func:`~sb3_latentswarm.agent.export_onnx`
    :param providers: onnxruntime execution providers (default: the CPU)
    :param intra_op_num_threads: threads of one step (default 1: one UAV's step is small, and a computer on a UAV runs
        other processes)
    :raise ImportError: without onnxruntime (``pip install "sb3-latentswarm[deploy]"``)
    :raise ValueError: for a zip file (a saved model), a file without the metadata :func:`export_onnx` writes, of a
        format this runtime does not read (:data:`FORMATS`), or whose format does not match its metadata

    A file of an adapted env's policy (format 3 or 4) takes the observations that
    :class:`~sb3_latentswarm.agent.LatentSwarmAgent` takes for that policy: ``local_obs``, ``proprio`` (e_dim may be
    0) and, where its env has positions, ``position`` (``(position_dims,)``), with the same checks.
    """

    def __init__(self, path: str | os.PathLike[str], providers: list[str] | None = None,
                 intra_op_num_threads: int = 1) -> None:
        import onnxruntime as ort

        with open(path, "rb") as handle:
            if handle.read(4) == b"PK\x03\x04":
                raise ValueError(f"{os.fspath(path)!r} is a zip file (a saved LatentSwarmPPO?): OnnxSwarmAgent reads "
                                 "the .onnx files of export_onnx; step a saved model with "
                                 "LatentSwarmAgent(LatentSwarmPPO.load(path))")
        options = ort.SessionOptions()
        options.intra_op_num_threads = int(intra_op_num_threads)
        self.session = ort.InferenceSession(os.fspath(path), options, providers=providers or ["CPUExecutionProvider"])
        raw = self.session.get_modelmeta().custom_metadata_map.get(_METADATA_KEY)
        if raw is None:
            raise ValueError(f"{os.fspath(path)!r} has no {_METADATA_KEY!r} metadata: export it with export_onnx")
        self.metadata: dict[str, Any] = json.loads(raw)
        found = self.metadata.get("format")
        if found not in FORMATS.values():
            raise ValueError(f"{os.fspath(path)!r} has export format {found!r}; this runtime reads "
                             f"{sorted(FORMATS.values())}")
        meta = self.metadata
        self.delay_aware: bool = bool(meta.get("delay_aware", False))
        """Whether :meth:`step` reads ``message_ages`` (an exported delay-aware policy, formats 2 and 4)."""
        self.message_expiry: int = int(meta.get("message_expiry", 0))
        """E, the largest message age in steps the policy was built for (0 without delayed links)."""
        position_key = meta.get("position_key", "proprio")  # (formats 1 and 2 do not write it: the swarm env's)
        adapted = position_key != "proprio"
        if position_key not in ("proprio", "position", None) or found != FORMATS[adapted, self.delay_aware]:
            raise ValueError(f"{os.fspath(path)!r}: format {found} does not match delay_aware={self.delay_aware} "
                             f"and position_key={position_key!r}")
        self._names = onnx_io_names(self.delay_aware, position_key == "position")
        self.spec = AgentSpec(tuple(meta["local_obs_shape"]), int(meta["proprio_dim"]), int(meta["message_dim"]),
                              int(meta["action_dim"]), tuple(meta["action_low"]), tuple(meta["action_high"]),
                              position_key, int(meta.get("position_dims", AgentSpec.position_dims)))
        self.state_dims = tuple(int(d) for d in meta["state_dims"])
        self._state: list[np.ndarray] | None = None
        self._message = np.zeros((1, self.spec.message_dim), dtype=np.float32)
        self._rng = np.random.default_rng()

    @property
    def message_dim(self) -> int:
        """d = d_mu + d_tau, the floats of one message."""
        return self.spec.message_dim

    def reset(self, seed: int | None = None) -> None:
        """Start an episode: the latent state becomes zero. ``seed`` seeds the generator of sampled actions."""
        self._state = [np.zeros((1, dim), dtype=np.float32) for dim in self.state_dims]
        self._message = np.zeros((1, self.spec.message_dim), dtype=np.float32)
        self._rng = np.random.default_rng(seed)

    def message(self) -> np.ndarray:
        """z = [mu; tau], the message this UAV broadcasts now, float32, (d,) (zero right after :meth:`reset`).

        :raise RuntimeError: before the first :meth:`reset`
        """
        self._current_state()
        return self._message[0].copy()

    def step(self, observation: Any, received_messages: Any, deterministic: bool = False, noise: Any = None,
             rng: np.random.Generator | None = None, return_info: bool = False, message_ages: Any = None) -> Any:
        """One step: see :meth:`LatentSwarmAgent.step <sb3_latentswarm.agent.LatentSwarmAgent.step>` (same arguments,
        results and errors; ``message_ages`` for a delay-aware file)."""
        state = self._current_state()
        arrays = check_step(self.spec, observation, received_messages, deterministic, noise, rng, self._rng)
        age = pooled_message_age(message_ages, arrays.message_count, self.message_expiry, self.delay_aware)
        eps = np.zeros(self.spec.action_dim, dtype=np.float32) if arrays.noise is None else arrays.noise
        state_names, _, output_names = self._names
        feed = dict(zip(state_names, state))
        feed.update(local_obs=arrays.local_obs[None], proprio=arrays.proprio[None],
                    message_mean=arrays.message_mean[None], message_count=np.array([arrays.message_count], dtype=np.int64),
                    noise=eps[None])
        if arrays.position is not None:  # (an adapted layout with positions: check_step required the key)
            feed["position"] = arrays.position[None]
        if age is not None:
            feed["message_age"] = np.array([[age]], dtype=np.float32)
        outputs = self.session.run(list(output_names), feed)
        self._state = outputs[1 : 1 + len(state_names)]
        self._message = outputs[-2]
        action = outputs[0][0]
        if not return_info:
            return action
        info = AgentStepInfo(
            message=self.message(),
            received_message=arrays.message_mean,
            has_message=arrays.message_count > 0,
            predicted_message=outputs[-1][0],
            best_message=self._state[_STATE_NAMES.index("prev_message")][0],
        )
        return action, info

    def _current_state(self) -> list[np.ndarray]:
        if self._state is None:
            raise RuntimeError("OnnxSwarmAgent: call reset() before message() or step()")
        return self._state
