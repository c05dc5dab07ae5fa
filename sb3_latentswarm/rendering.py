"""Episode rendering: an animated GIF (or MP4) of one episode and a figure of the UAV trajectories.

The frames come from ``SwarmReconEnv(render_mode="rgb_array")`` (map estimate, true obstacles not yet found, current
footprints, UAVs, live links and a coverage bar); this module adds the UAV trails and a dropout marker (a red frame
around the image at steps where some UAV received nothing) and writes the files with imageio and matplotlib. MP4
needs the ``imageio-ffmpeg`` package (``pip install "sb3-latentswarm[video]"``); GIF needs nothing more.
"""

from __future__ import annotations

import contextlib
from pathlib import Path

import numpy as np
import torch as th

from sb3_latentswarm.config import SwarmConfig
from sb3_latentswarm.envs.swarm_recon import AGENT_COLOURS

ANIMATION_FORMATS = (".gif", ".mp4")
_TRAIL_COLOURS = AGENT_COLOURS.astype(np.uint8)  # the env's palette: a UAV's trail has the colour of its square


def run_episode(model, config: SwarmConfig, seed: int = 0, condition: str = "proposed", deterministic: bool = True):
    """Play one episode and keep every rendered frame.

    :param model: a ``LatentSwarmPPO``, a planner with ``predict``, or ``None`` for uniformly random actions
    :param config: the env config; ``condition`` ``"full_comm"`` / ``"no_comm"`` overrides its ``link_mode``
    :param condition: one of the evaluation conditions (``"proposed"``, ``"full_comm"``, ``"no_comm"``,
        ``"no_predictor"``, ``"no_memory"``)
    :param deterministic: act with the mean action; ``False`` samples the policy with torch's generator seeded from
        ``seed`` inside ``torch.random.fork_rng`` (the global generator is left as it was)
    :return: (frames (T+1, H, W, 3) uint8, positions (T+1, N, 3) in metres, dropouts (T+1,) bool, final infos)
    """
    from sb3_latentswarm.envs import SwarmReconEnv
    from sb3_latentswarm.evaluation import condition_config, policy_switches

    env = SwarmReconEnv(condition_config(config, condition, config.p_fail), render_mode="rgb_array")
    observations, _ = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    policy = getattr(model, "policy", None)
    switches = policy_switches(policy, condition) if policy is not None else contextlib.nullcontext()
    frames, positions, dropouts, state, infos = [], [], [], None, {}
    with switches, th.random.fork_rng():
        th.manual_seed(seed)  # the action noise of deterministic=False
        while True:
            frames.append(env.render())
            positions.append(env.positions.copy())
            link_rows = np.stack([obs["link_row"] for obs in observations.values()])
            dropouts.append(bool(np.any(link_rows.sum(-1) == 0)))
            if not env.agents:
                break
            if model is None:
                shape = env.action_space(env.agents[0]).shape
                actions = {agent: rng.uniform(-1, 1, shape).astype(np.float32) for agent in env.agents}
            else:
                actions, state = model.predict(observations, state=state, deterministic=deterministic)
            observations, _, _, _, infos = env.step(actions)
    return np.stack(frames), np.stack(positions), np.array(dropouts), infos


def _draw_trails(frames: np.ndarray, positions: np.ndarray, config: SwarmConfig) -> np.ndarray:
    """Overlay each UAV's past path on the frames (image rows start below the coverage bar)."""
    frames = frames.copy()
    n_frames, height, width, _ = frames.shape
    cells = max(config.grid_width, config.grid_height)
    px = max(1, 480 // cells)
    map_h, map_w = config.grid_height * px, config.grid_width * px
    bar = height - map_h
    x_max, y_max = config.arena_size
    cols = np.clip((positions[..., 0] / x_max * map_w).astype(int), 0, map_w - 1)  # (T, N)
    rows = np.clip(((1.0 - positions[..., 1] / y_max) * map_h).astype(int), 0, map_h - 1) + bar
    colours = _TRAIL_COLOURS[np.arange(positions.shape[1]) % len(_TRAIL_COLOURS)]
    for t in range(1, n_frames):
        # every frame shows the trail so far: paint the newest point into this and all later frames
        frames[t:, rows[t - 1], cols[t - 1]] = colours
    return frames


def _mark_dropouts(frames: np.ndarray, dropouts: np.ndarray, border: int = 3) -> np.ndarray:
    frames = frames.copy()
    marked = frames[dropouts]
    for edge in (np.s_[:, :border], np.s_[:, -border:], np.s_[:, :, :border], np.s_[:, :, -border:]):
        marked[edge] = (220, 30, 30)
    frames[dropouts] = marked
    return frames


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

    :param output: file path ending in ``.gif`` or ``.mp4``
    :param fps: frames per second of the animation (> 0)
    :param max_frames: longer episodes are subsampled evenly to at most this many frames (>= 2)
    :param deterministic: act with the policy's mean action (``False``: sample it, reproducibly from ``seed``)
    """
    import imageio.v2 as imageio

    output = Path(output)
    _check_animation_args(output, fps, max_frames)
    frames, positions, dropouts, _ = run_episode(model, config, seed=seed, condition=condition, deterministic=deterministic)
    frames = _mark_dropouts(_draw_trails(frames, positions, config), dropouts)
    if len(frames) > max_frames:
        frames = frames[np.linspace(0, len(frames) - 1, max_frames).round().astype(int)]
    output.parent.mkdir(parents=True, exist_ok=True)
    if output.suffix.lower() == ".gif":
        imageio.mimsave(output, list(frames), duration=1.0 / fps, loop=0)
    else:  # H.264 in yuv420p needs even frame sizes: pad one row/column of the border colour where needed
        pad = ((0, 0), (0, frames.shape[1] % 2), (0, frames.shape[2] % 2), (0, 0))
        imageio.mimsave(output, list(np.pad(frames, pad, mode="edge")), fps=fps, macro_block_size=1)
    plot_trajectories(positions, dropouts, config, output.with_name(output.stem + "_trajectories.png"))
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
