"""``sb3-latentswarm render``: an animated GIF (or MP4) of one episode and a trajectory figure."""

from __future__ import annotations

import argparse
import functools
from pathlib import Path

from sb3_latentswarm.cli.evaluate import check_model_env, load_model
from sb3_latentswarm.cli.settings import preset_from_args
from sb3_latentswarm.utils.locks import output_lock


def command_render(args: argparse.Namespace) -> int:
    """``render``: one episode of ``--model`` (or random actions) under ``--condition``, to ``--output``; with
    ``--env``, an episode of that adapted env in its own frames."""
    from sb3_latentswarm.rendering import check_model_fits, render_adapted_episode, render_episode

    model = load_model(args) if args.model else None
    if model is not None:
        check_model_env(args, model)
    preset = preset_from_args(args, model)
    if preset.env is not None:  # an adapted env: its own frames
        render = functools.partial(render_adapted_episode, model, preset.env, preset.config)
    else:
        check_model_fits(model, preset.config)
        render = functools.partial(render_episode, model, preset.config)
    with output_lock(Path(args.output).parent):  # the folder the animation is written into
        path = render(args.output, seed=args.seed, condition=args.condition, fps=args.fps, deterministic=not args.stochastic)
    print(f"Wrote {path}")
    return 0
