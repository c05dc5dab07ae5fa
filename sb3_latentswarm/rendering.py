"""Episode rendering: an animated GIF (or MP4) of one episode and a figure of the UAV trajectories.

The frames come from ``SwarmReconEnv(render_mode="rgb_array")`` (map estimate, true obstacles not yet found, current
footprints, UAVs, live links and a coverage bar); this module adds the UAV trails and a dropout marker (a red frame
around the image at steps where some UAV received nothing) and writes the files with imageio and matplotlib. MP4
needs the ``imageio-ffmpeg`` package (``pip install "sb3-latentswarm[video]"``); GIF needs nothing more.
"""

from __future__ import annotations

import contextlib
from pathlib import Path
from typing import Any

import numpy as np
import torch as th

from sb3_latentswarm.config import SwarmConfig
from sb3_latentswarm.envs.swarm_recon import AGENT_COLOURS

ANIMATION_FORMATS = (".gif", ".mp4")
_TRAIL_COLOURS = AGENT_COLOURS.astype(np.uint8)  # the env's palette: a UAV's trail has the colour of its square


def _episode(model, config: SwarmConfig, seed: int, condition: str, deterministic: bool, keep_frame):
    """Play one episode on a one-swarm batch (B = 1) of the core that evaluation and training step; yield
    ``(t, frame or None, positions (N, 3), dropout, infos, last)`` per step, rendering only the frames
    ``keep_frame(t)`` asks for (the others are ``None``), so no episode's worth of frames is held."""
    from sb3_latentswarm.envs.batched_core import SwarmBatch
    from sb3_latentswarm.envs.swarm_recon import render_frame
    from sb3_latentswarm.evaluation import condition_config, policy_switches
    from sb3_latentswarm.latent_ppo.policies import LatentSwarmPolicy

    check_model_fits(model, config)
    core = SwarmBatch(condition_config(config, condition, config.p_fail), n_swarms=1)
    core.reset(seeds=[seed])
    agents = [f"uav_{i}" for i in range(core.n_agents)]
    rng = np.random.default_rng(seed)
    policy = getattr(model, "policy", None)
    switches = policy_switches(policy, condition) if isinstance(policy, LatentSwarmPolicy) else contextlib.nullcontext()
    infos: dict[str, dict[str, Any]] = {}
    state, t, last = None, 0, False
    with switches, th.random.fork_rng():
        th.manual_seed(seed)  # the action noise of deterministic=False
        while True:
            dropout = bool(np.any(core.link_rows[0].sum(-1) == 0))
            frame = render_frame(core, 0) if (last or keep_frame(t)) else None
            yield t, frame, core.positions[0].copy(), dropout, infos, last
            if last:
                return
            if model is None:
                actions = rng.uniform(-1, 1, (core.n_agents, 4)).astype(np.float32)
            else:
                obs = {key: getattr(core, attr)[0].copy() for key, attr in _ACTOR_ARRAYS.items()}
                actions, state = model.predict(obs, state=state, deterministic=deterministic)
            _, terminated, truncated = core.step(core.check_actions(np.asarray(actions)[None]))
            infos = dict(zip(agents, core.step_infos(terminated, truncated)[0]))
            last = bool(terminated[0] or truncated[0])
            t += 1


# actor observation key -> the SwarmBatch array holding it, (B, N, ...)
_ACTOR_ARRAYS = {"local_obs": "local_obs", "proprio": "proprio", "link_row": "link_rows"}


def check_model_fits(model, config: SwarmConfig) -> None:
    """Refuse a model whose observation shapes differ from ``config``'s (another map size or sensor range).

    The number of agents may differ (the policy's parameters do not depend on it); the map and the sensor footprint may
    not: a policy trained on another map would be rendered on inputs it never saw, or fail inside torch.

    :raise ValueError: naming the differing keys, the model's shapes and the config's
    """
    space = getattr(model, "observation_space", None)
    if model is None or space is None or not hasattr(space, "spaces"):
        return
    from sb3_latentswarm.envs.batched_core import agent_observation_space

    expected = agent_observation_space(config)
    differ = [
        f"{key}: model {space[key].shape}, config {expected[key].shape}"
        for key in ("local_obs", "global_map")
        if key in space.spaces and space[key].shape != expected[key].shape
    ]
    if differ:
        raise ValueError(
            f"the model was trained on another map or sensor range than the config "
            f"(grid {config.grid_width}x{config.grid_height}, sensor_range {config.sensor_range}): {'; '.join(differ)}. "
            f"Render it on its training config (omit --preset/--set grid_width, grid_height, sensor_range)"
        )


def run_episode(model, config: SwarmConfig, seed: int = 0, condition: str = "proposed", deterministic: bool = True):
    """Play one episode and keep every rendered frame (a one-swarm batch, B = 1, of the core that evaluation and
    training step; for short episodes: :func:`render_episode` streams instead).

    :param model: a ``LatentSwarmPPO``, a planner with ``predict``, or ``None`` for uniformly random actions
    :param config: the env config; the condition replaces its ``link_mode`` (and keeps its ``p_fail``)
    :param seed: the episode's env seed (as episode seed ``seed`` of :func:`~sb3_latentswarm.evaluation.evaluate`)
    :param condition: a name of :data:`~sb3_latentswarm.evaluation.CONDITION_TABLE` (``"proposed"``, ``"full_comm"``,
        ``"no_comm"``, ``"no_predictor"``, ``"no_memory"``, ...)
    :param deterministic: act with the mean action; ``False`` samples the policy with torch's generator seeded from
        ``seed`` inside ``torch.random.fork_rng`` (the global generator is left as it was)
    :return: (frames (T+1, H, W, 3) uint8, positions (T+1, N, 3) in metres, dropouts (T+1,) bool, final infos
        ``{agent: info}`` as :meth:`~sb3_latentswarm.envs.SwarmReconEnv.step` returns them)
    :raise ValueError: for a model trained on another map or sensor range (:func:`check_model_fits`)
    """
    frames, positions, dropouts, final_infos = [], [], [], {}
    for _, frame, position, dropout, step_infos, _ in _episode(model, config, seed, condition, deterministic, lambda t: True):
        frames.append(frame)
        positions.append(position)
        dropouts.append(dropout)
        final_infos = step_infos
    return np.stack(frames), np.stack(positions), np.array(dropouts), final_infos


def _pixels(positions: np.ndarray, config: SwarmConfig, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Image rows and columns of positions (..., 3) in metres (image rows start below the coverage bar)."""
    cells = max(config.grid_width, config.grid_height)
    px = max(1, 480 // cells)
    map_h, map_w = config.grid_height * px, config.grid_width * px
    x_max, y_max = config.arena_size
    cols = np.clip((positions[..., 0] / x_max * map_w).astype(int), 0, map_w - 1)
    rows = np.clip(((1.0 - positions[..., 1] / y_max) * map_h).astype(int), 0, map_h - 1) + (height - map_h)
    return rows, cols


def _decorate(frame: np.ndarray, past: np.ndarray, dropout: bool, config: SwarmConfig, border: int = 3) -> np.ndarray:
    """One frame with the UAV trails so far (``past``: the positions (t, N, 3) before this frame) and, when some UAV
    received nothing, a red border."""
    frame = frame.copy()
    if len(past):
        rows, cols = _pixels(past, config, frame.shape[0])  # (t, N)
        colours = _TRAIL_COLOURS[np.arange(past.shape[1]) % len(_TRAIL_COLOURS)]
        frame[rows, cols] = np.broadcast_to(colours, (*rows.shape, 3))
    if dropout:
        for edge in (np.s_[:border], np.s_[-border:], np.s_[:, :border], np.s_[:, -border:]):
            frame[edge] = (220, 30, 30)
    return frame


def render_episode(
    model,
    config: SwarmConfig,
    output: str | Path,
    seed: int = 0,
    condition: str = "proposed",
    fps: int = 10,
    max_frames: int = 400,
    deterministic: bool = True,
) -> Path:
    """Write an animated GIF or MP4 of one episode to ``output`` and a trajectory figure next to it
    (``*_trajectories.png``).

    Frames are written as the episode runs (one frame in memory at a time). Episodes that could be longer than
    ``max_frames`` keep every k-th step, k = ceil(max_steps / (max_frames - 1)), and always the last one; each frame
    lasts 1 / ``fps`` seconds (GIF delays are stored in centiseconds, so 1000 / fps ms is rounded to 10 ms).

    :param output: file path ending in ``.gif`` or ``.mp4``
    :param fps: frames per second of the animation (> 0)
    :param max_frames: at most this many frames are written (>= 2)
    :param deterministic: act with the policy's mean action (``False``: sample it, reproducibly from ``seed``)
    :raise ValueError: for a bad argument, or a model trained on another map or sensor range, before any work
    """
    import imageio.v2 as imageio
    from PIL import Image

    output = Path(output)
    _check_animation_args(output, fps, max_frames)
    check_model_fits(model, config)
    stride = max(1, -(-config.max_steps // (max_frames - 1)))  # multiples of stride plus the last step: <= max_frames
    output.parent.mkdir(parents=True, exist_ok=True)
    gif = output.suffix.lower() == ".gif"
    positions, dropouts, palette_frames = [], [], []
    writer = None if gif else imageio.get_writer(output, fps=fps, macro_block_size=1)
    try:
        for _, frame, position, dropout, _, _ in _episode(
            model, config, seed, condition, deterministic, lambda t: t % stride == 0
        ):
            positions.append(position)
            dropouts.append(dropout)
            if frame is None:
                continue
            frame = _decorate(frame, np.asarray(positions[:-1]).reshape(-1, position.shape[0], 3), dropout, config)
            if writer is None:  # a GIF is written at the end: keep each frame as the 1-byte palette image it becomes
                palette_frames.append(Image.fromarray(frame).convert("P", palette=Image.Palette.ADAPTIVE))
            else:  # H.264 in yuv420p needs even frame sizes: pad one row/column of the border colour where needed
                writer.append_data(np.pad(frame, ((0, frame.shape[0] % 2), (0, frame.shape[1] % 2), (0, 0)), mode="edge"))
    finally:
        if writer is not None:
            writer.close()
    if gif:  # pillow reads duration in milliseconds per frame (imageio passes it on unchanged)
        first, *rest = palette_frames
        first.save(output, save_all=True, append_images=rest, duration=1000.0 / fps, loop=0)
    plot_trajectories(np.stack(positions), np.array(dropouts), config, output.with_name(output.stem + "_trajectories.png"))
    return output


def _check_animation_args(output: Path, fps: int, max_frames: int) -> None:
    """Fail before running the episode when the animation could not be written."""
    suffix = output.suffix.lower()
    if suffix not in ANIMATION_FORMATS:
        raise ValueError(f"output must end in one of {ANIMATION_FORMATS}, got {str(output)!r}")
    if suffix == ".mp4":
        try:
            import imageio_ffmpeg  # noqa: F401
        except ImportError as error:
            raise ValueError(
                "output: writing .mp4 needs imageio-ffmpeg (pip install 'sb3-latentswarm[video]'); use .gif otherwise"
            ) from error
    if not fps > 0:
        raise ValueError(f"fps must be > 0, got {fps}")
    if max_frames < 2:
        raise ValueError(f"max_frames must be >= 2, got {max_frames}")


def plot_trajectories(positions: np.ndarray, dropouts: np.ndarray, config: SwarmConfig, path: str | Path) -> Path:
    """Top view of the UAV paths over the arena; steps with some UAV in dropout are marked with crosses."""
    from matplotlib.figure import Figure  # no pyplot: the caller's matplotlib backend is left alone

    x_max, y_max = config.arena_size
    fig = Figure(figsize=(5, 5))
    ax = fig.subplots()
    for i in range(positions.shape[1]):
        ax.plot(positions[:, i, 0], positions[:, i, 1], lw=1.2, color=_TRAIL_COLOURS[i % len(_TRAIL_COLOURS)] / 255.0,
                label=f"uav_{i}")
        ax.plot(*positions[0, i, :2], "o", color=_TRAIL_COLOURS[i % len(_TRAIL_COLOURS)] / 255.0)
        ax.plot(positions[dropouts, i, 0], positions[dropouts, i, 1], "x", ms=3, alpha=0.4, color="red")
    ax.set_xlim(0, x_max)
    ax.set_ylim(0, y_max)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title("Trajectories (o: start, x: a UAV in dropout)")
    ax.legend(loc="upper right", fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    return Path(path)
