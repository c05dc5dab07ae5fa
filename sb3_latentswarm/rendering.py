"""Episode rendering: an animated GIF (or MP4) of one episode and a figure of the UAV trajectories.

The frames come from ``SwarmReconEnv(render_mode="rgb_array")`` (map estimate, true obstacles not yet found, current
footprints, UAVs, live links and a coverage bar); this module adds the UAV trails, a dropout marker (a red border
around the map at steps where some UAV received nothing) and a legend panel beside the map that names every colour
and shows the step, the coverage and the collisions so far (:func:`legend_figure`), and writes the files with imageio
and matplotlib. MP4 needs the ``imageio-ffmpeg`` package (``pip install "sb3-latentswarm[video]"``); GIF needs nothing
more.
"""

from __future__ import annotations

import contextlib
from pathlib import Path
from typing import Any

import numpy as np
import torch as th

from sb3_latentswarm.config import SwarmConfig
from sb3_latentswarm.envs.swarm_recon import AGENT_COLOURS, FOOTPRINT_TINT, RENDER_COLOURS

ANIMATION_FORMATS = (".gif", ".mp4")
_TRAIL_COLOURS = AGENT_COLOURS.astype(np.uint8)  # the env's palette: a UAV's trail has the colour of its square
DROPOUT_BORDER = (220, 30, 30)
"""RGB colour of the border drawn around the map at a step where some UAV received no message (N_t^i empty)."""
LEGEND_WIDTH = 250
"""Width (pixels) of the legend panel beside the map; it is at least :data:`LEGEND_MIN_HEIGHT` pixels high (a shorter
map is padded below in white)."""
LEGEND_MIN_HEIGHT = 430
STATUS_HEIGHT = 50
"""Height (pixels) of the legend panel's status lines (step, coverage, collisions), under its two-line title."""
_TITLE_HEIGHT = 40


def _episode(model, config: SwarmConfig, seed: int, condition: str, deterministic: bool, keep_frame):
    """Play one episode on a one-swarm batch (B = 1) of the core that evaluation and training step; yield
    ``(t, frame or None, positions (N, 3), dropout, infos, last)`` per step (``infos``: the frame's coverage and
    collisions so far, as :meth:`~sb3_latentswarm.envs.batched_core.SwarmBatch.step_infos` builds them), rendering only
    the frames
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
    not_done = np.zeros(1, dtype=bool)
    infos: dict[str, dict[str, Any]] = dict(zip(agents, core.step_infos(not_done, not_done)[0]))  # after the reset
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
    """One frame with the UAV trails so far (``past``: the positions (t, N, 3) before this frame, each a dot of 2 x 2
    pixels) and, when some UAV received nothing, a red border."""
    frame = frame.copy()
    if len(past):
        rows, cols = _pixels(past, config, frame.shape[0])  # (t, N)
        colours = np.broadcast_to(_TRAIL_COLOURS[np.arange(past.shape[1]) % len(_TRAIL_COLOURS)], (*rows.shape, 3))
        for d_row, d_col in ((0, 0), (0, 1), (1, 0), (1, 1)):
            frame[np.minimum(rows + d_row, frame.shape[0] - 1), np.minimum(cols + d_col, frame.shape[1] - 1)] = colours
    if dropout:
        for edge in (np.s_[:border], np.s_[-border:], np.s_[:, :border], np.s_[:, -border:]):
            frame[edge] = DROPOUT_BORDER
    return frame


def _rgb(colour) -> tuple[float, float, float]:
    """An RGB colour of 0-255 values as matplotlib's 0-1 triple."""
    red, green, blue = (float(c) / 255.0 for c in colour)
    return red, green, blue


def legend_figure(n_agents: int, title: str = "", height: int = LEGEND_MIN_HEIGHT, width: int = LEGEND_WIDTH):
    """The legend panel of a rendered episode as a matplotlib ``Figure`` of ``width`` x ``height`` pixels (dpi 100).

    It names what :func:`~sb3_latentswarm.envs.swarm_recon.render_frame` and this module draw: the coverage bar, the
    map estimate's cells (not yet seen, free, obstacle) and the obstacles no UAV has seen yet, each UAV's colour (its
    square, trail and sensor footprint), the links (both ways, one way) and the red dropout border. ``title`` (say:
    the condition and the episode seed) stands above it, and :data:`STATUS_HEIGHT` pixels under the title are left
    blank for the status lines :func:`render_episode` writes per frame (step, coverage, collisions).

    :param n_agents: N, the number of UAVs (>= 1); colours repeat every 7 UAVs, as in the frames
    :param title: at most two short lines
    :param height: pixels (>= 100)
    :param width: pixels (>= 100)
    :raise ValueError: for ``n_agents`` < 1 or a size under 100 pixels
    """
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    if n_agents < 1:
        raise ValueError(f"n_agents must be >= 1, got {n_agents}")
    if height < 100 or width < 100:
        raise ValueError(f"height and width must be >= 100 pixels, got {height} x {width}")
    fig = Figure(figsize=(width / 100, height / 100), dpi=100, facecolor="white")
    fig.text(0.05, 1 - 8 / height, title, va="top", ha="left", fontsize=8.5, weight="bold")
    colours = {name: _rgb(colour) for name, colour in RENDER_COLOURS.items()}
    free = np.array(RENDER_COLOURS["free"], dtype=float)

    def cell(name: str, label: str) -> Patch:
        return Patch(facecolor=colours[name], edgecolor="0.55", linewidth=0.6, label=label)

    uavs = [
        Line2D([], [], color=_rgb(AGENT_COLOURS[i]), marker="s", markersize=7, linestyle=":", linewidth=1.5,
               label=", ".join(f"uav_{j}" for j in range(i, n_agents, len(AGENT_COLOURS))) + ": square, trail")
        for i in range(min(n_agents, len(AGENT_COLOURS)))
    ]
    tint = (1 - FOOTPRINT_TINT) * free + FOOTPRINT_TINT * AGENT_COLOURS[0]
    handles = [
        Patch(facecolor=colours["coverage"], edgecolor=colours["bar"], linewidth=2,
              label="coverage bar (top):\nshare of cells seen"),
        cell("unseen", "cell not yet seen"),
        cell("free", "seen, free"),
        cell("obstacle", "seen, obstacle"),
        cell("obstacle_unseen", "obstacle not yet seen\n(ground truth)"),
        *uavs,
        Patch(facecolor=_rgb(tint), edgecolor="0.55", linewidth=0.6, label="tinted cells: a UAV's\nsensor footprint now"),
        Line2D([], [], color=colours["link_both_ways"], linewidth=2.5, label="link, both ways"),
        Line2D([], [], color=colours["link_one_way"], linewidth=2.5, label="link, one way"),
        Patch(facecolor="white", edgecolor=_rgb(DROPOUT_BORDER), linewidth=2.5,
              label="red border: a UAV got no\nmessage this step (dropout)"),
    ]
    top = _TITLE_HEIGHT + STATUS_HEIGHT
    fig.legend(handles=handles, loc="upper left", bbox_to_anchor=(0.0, 1 - top / height), frameon=False, fontsize=8,
               handlelength=1.8, labelspacing=0.55, borderaxespad=0.3)
    return fig


def _rasterise(fig) -> np.ndarray:
    """A matplotlib figure as an (H, W, 3) uint8 array."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].copy()


class _LegendPanel:
    """The legend panel as an RGB array: the legend rasterised once, the status lines redrawn per frame in their own
    small figure (a full redraw of the legend would cost more than the episode's step)."""

    def __init__(self, n_agents: int, title: str, height: int) -> None:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure

        self.legend = _rasterise(legend_figure(n_agents, title, height=height))
        status_figure = Figure(figsize=(LEGEND_WIDTH / 100, STATUS_HEIGHT / 100), dpi=100, facecolor="white")
        self.status = status_figure.text(0.05, 0.95, "", va="top", ha="left", fontsize=8.5, family="monospace")
        self.canvas = FigureCanvasAgg(status_figure)

    def image(self, status: str) -> np.ndarray:
        """(height, LEGEND_WIDTH, 3) uint8: the legend with ``status`` under its title."""
        self.status.set_text(status)
        self.canvas.draw()
        panel = self.legend.copy()
        panel[_TITLE_HEIGHT : _TITLE_HEIGHT + STATUS_HEIGHT] = np.asarray(self.canvas.buffer_rgba())[..., :3]
        return panel


def _with_legend(frame: np.ndarray, panel: np.ndarray) -> np.ndarray:
    """``frame`` with ``panel`` on its right; the shorter of the two is padded below in white."""
    height = max(frame.shape[0], panel.shape[0])
    pad = [np.full((height - part.shape[0], part.shape[1], 3), 255, np.uint8) for part in (frame, panel)]
    return np.concatenate([np.concatenate([frame, pad[0]]), np.concatenate([panel, pad[1]])], axis=1)


class _Animation:
    """Frames into a GIF (kept as 1-byte palette images and written at :meth:`close`) or an MP4 (written as they
    come, padded to even sizes for H.264 in yuv420p); each frame lasts 1 / ``fps`` seconds."""

    def __init__(self, output: Path, fps: int) -> None:
        import imageio.v2 as imageio

        self.output, self.fps = output, fps
        self.gif = output.suffix.lower() == ".gif"
        self.palette_frames: list[Any] = []
        self.writer = None if self.gif else imageio.get_writer(output, fps=fps, macro_block_size=1)

    def add(self, frame: np.ndarray) -> None:
        from PIL import Image

        if self.writer is None:
            self.palette_frames.append(Image.fromarray(frame).convert("P", palette=Image.Palette.ADAPTIVE))
        else:
            self.writer.append_data(np.pad(frame, ((0, frame.shape[0] % 2), (0, frame.shape[1] % 2), (0, 0)), mode="edge"))

    def close(self, write: bool = True) -> None:
        """Finish the file (a GIF is written only now; ``write=False`` after a failure: no GIF)."""
        if self.writer is not None:
            self.writer.close()
        elif write and self.palette_frames:  # pillow reads duration in milliseconds per frame
            first, *rest = self.palette_frames
            first.save(self.output, save_all=True, append_images=rest, duration=1000.0 / self.fps, loop=0)


def render_episode(
    model,
    config: SwarmConfig,
    output: str | Path,
    seed: int = 0,
    condition: str = "proposed",
    fps: int = 10,
    max_frames: int = 400,
    deterministic: bool = True,
    legend: bool = True,
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
    :param legend: put the legend panel (:func:`legend_figure`; condition, episode seed, way of acting, step, coverage
        and collisions so far) on the right of each frame
    :raise ValueError: for a bad argument, or a model trained on another map or sensor range, before any work
    """
    output = Path(output)
    _check_animation_args(output, fps, max_frames)
    check_model_fits(model, config)
    stride = max(1, -(-config.max_steps // (max_frames - 1)))  # multiples of stride plus the last step: <= max_frames
    output.parent.mkdir(parents=True, exist_ok=True)
    positions, dropouts = [], []
    panel = None
    animation = _Animation(output, fps)
    written = False
    try:
        for t, frame, position, dropout, infos, _ in _episode(
            model, config, seed, condition, deterministic, lambda t: t % stride == 0
        ):
            positions.append(position)
            dropouts.append(dropout)
            if frame is None:
                continue
            frame = _decorate(frame, np.asarray(positions[:-1]).reshape(-1, position.shape[0], 3), dropout, config)
            if legend:
                if panel is None:
                    acting = "mean actions" if deterministic else "sampled actions"
                    actor = "random actions" if model is None else acting
                    title = f"{condition}, episode seed {seed}\n{actor}"
                    panel = _LegendPanel(position.shape[0], title, max(frame.shape[0], LEGEND_MIN_HEIGHT))
                info: dict[str, Any] = next(iter(infos.values()), {})
                status = (f"step {t:>4} / {config.max_steps}\ncoverage {100 * info.get('coverage', 0.0):5.1f} %\n"
                          f"collisions {info.get('collisions', 0):>3}")
                frame = _with_legend(frame, panel.image(status))
            animation.add(frame)
        written = True
    finally:
        animation.close(write=written)
    plot_trajectories(np.stack(positions), np.array(dropouts), config, output.with_name(output.stem + "_trajectories.png"))
    return output


def render_adapted_episode(
    model,
    env: Any,
    config: SwarmConfig,
    output: str | Path,
    seed: int = 0,
    condition: str = "proposed",
    fps: int = 10,
    max_frames: int = 400,
    deterministic: bool = True,
) -> Path:
    """Write an animated GIF or MP4 of one episode of an adapted env (``render --env``) to ``output``: the env's own
    frames (``render_mode="rgb_array"``, passed to its factory with ``env.kwargs``) with a caption under each one
    (condition, episode seed, way of acting, step, the mean agent return so far, and how many agents received no
    message at that step, i.e. acted in dropout, Sec. III-C).

    One env copy reset with ``seed``, the link model of ``condition`` at ``config.p_fail`` and the policy's switches of
    ``condition``; sampled actions draw from a torch generator seeded with ``seed`` (random actions from the action
    space seeded with it), so the same call gives the same GIF. With mean actions the episode is the one
    ``evaluate --env --deterministic`` plays as its episode 0 when ``seed`` is its evaluation seed. Every step is a
    frame, up to ``max_frames``; there is no trajectory figure (an adapted env has no map to draw it on).

    :param model: a :class:`~sb3_latentswarm.LatentSwarmPPO` trained on this env, or ``None`` for random actions
    :param env: the :class:`~sb3_latentswarm.envs.adapted_env.AdaptedEnv`
    :param config: its link fields (:meth:`Preset.with_env <sb3_latentswarm.presets.Preset.with_env>`)
    :raise ValueError: a bad argument or condition, or an env factory that takes no ``render_mode`` or returns no
        frame, before anything is written
    """
    from sb3_latentswarm.envs.adapted_env import AdaptedEnv
    from sb3_latentswarm.evaluation.conditions import check_condition, condition_config, policy_switches

    output = Path(output)
    _check_animation_args(output, fps, max_frames)
    condition = check_condition(condition).name
    framed = AdaptedEnv(env.name, {**env.kwargs, "render_mode": "rgb_array"})
    try:
        vec = framed.make_vec_env(1, condition_config(config, condition, config.p_fail), seed, monitor=False)
    except TypeError as error:
        raise ValueError(
            f"render --env {env.name}: the env factory must accept render_mode='rgb_array' (PettingZoo's convention) "
            f"to give frames: {error}"
        ) from error
    obs = vec.reset()
    first = vec.get_images()[0]
    if not isinstance(first, np.ndarray) or first.ndim != 3:
        vec.close()
        raise ValueError(f"render --env {env.name}: env.render() with render_mode='rgb_array' gave no RGB frame")
    n_agents = vec.num_envs
    vec.action_space.seed(seed)
    actor = "random actions" if model is None else ("mean actions" if deterministic else "sampled actions")
    switches = contextlib.nullcontext() if model is None else policy_switches(model.policy, condition)
    output.parent.mkdir(parents=True, exist_ok=True)
    animation = _Animation(output, fps)
    written = False
    try:
        with switches, th.random.fork_rng():
            th.manual_seed(seed)
            state, starts = None, np.ones(n_agents, dtype=bool)
            episode_return, t, done = 0.0, 0, False
            while not done and t < max_frames:
                dropout = int((obs["link_row"].sum(-1) == 0).sum())
                caption = (f"{condition}, episode seed {seed}, {actor}\nstep {t:>3}   return {episode_return:7.2f}   "
                           f"in dropout {dropout} / {n_agents}")
                animation.add(_with_caption(vec.get_images()[0], caption))
                if model is None:
                    actions = np.stack([vec.action_space.sample() for _ in range(n_agents)])
                else:
                    actions, state = model.predict(obs, state=state, episode_start=starts, deterministic=deterministic)
                obs, rewards, starts, _ = vec.step(actions)
                episode_return += float(np.mean(rewards))
                t, done = t + 1, bool(starts[0])
        written = True
    finally:
        animation.close(write=written)
        vec.close()
    return output


def _with_caption(frame: np.ndarray, caption: str, height: int = 36) -> np.ndarray:
    """``frame`` (H, W, 3) uint8 with ``caption`` (two lines) in black on a white band under it."""
    from PIL import Image, ImageDraw

    band = Image.new("RGB", (frame.shape[1], height), "white")
    ImageDraw.Draw(band).multiline_text((4, 2), caption, fill=(0, 0, 0))
    return np.concatenate([np.asarray(frame[..., :3], dtype=np.uint8), np.asarray(band)], axis=0)


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
