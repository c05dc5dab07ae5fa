"""The ``sb3-latentswarm`` command: ``train``, ``evaluate``, ``render`` and ``sweep``.

    sb3-latentswarm train --preset demo --evaluate          # the README's main job
    sb3-latentswarm train --preset coordination --seeds 3   # seeds 0, 1, 2: one single-thread process each
    sb3-latentswarm evaluate --model runs/demo/model.zip --p-fail-sweep   # on the env config saved with the model
    sb3-latentswarm render --model runs/demo/model.zip --output episode.gif
    sb3-latentswarm sweep --preset fast --seeds 5           # seeds x variants on Ray Tune, across-seed intervals

The package: :mod:`~sb3_latentswarm.cli.parser` (every option and its help), :mod:`~sb3_latentswarm.cli.settings`
(settings parsed and validated once, before any work), then one module per subcommand,
:mod:`~sb3_latentswarm.cli.train` (and :mod:`~sb3_latentswarm.cli.seeds` for ``train --seeds``),
:mod:`~sb3_latentswarm.cli.evaluate`, :mod:`~sb3_latentswarm.cli.render` and :mod:`~sb3_latentswarm.cli.sweep`, each
imported only when its command runs, so that ``--help`` answers without importing torch.
"""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

from sb3_latentswarm.cli.parser import build_parser
from sb3_latentswarm.cli.settings import check_arguments, parse_overrides

__all__ = ["USER_ERRORS", "build_parser", "main", "parse_overrides", "program_name", "resume_command"]

USER_ERRORS = (ValueError, TypeError, RuntimeError, OSError, ArithmeticError, MemoryError)
"""What a user's input can raise (bad settings, files, devices, torch's own checks): reported in one line, exit 2."""


def program_name() -> str:
    """The name the user ran this command by: ``basename(sys.argv[0])`` when that is one of the package's console
    scripts (``sb3-latentswarm``), else ``sb3-latentswarm`` (``python -m sb3_latentswarm.cli``, a test runner)."""
    import os
    from importlib.metadata import entry_points

    name = os.path.basename(sys.argv[0]) if sys.argv and sys.argv[0] else ""
    for suffix in ("-script.py", ".exe"):  # the launchers pip writes on Windows
        name = name.removesuffix(suffix)
    try:
        scripts = {ep.name for ep in entry_points(group="console_scripts") if ep.value.startswith(f"{__name__}:")}
    except Exception:  # broken package metadata must not stop a run from printing how to resume it
        scripts = set()
    return name if name in scripts else "sb3-latentswarm"


def resume_command(output: Path) -> str:
    """``sb3-latentswarm train --resume --output OUTPUT``, by the name the user ran (:func:`program_name`)."""
    import shlex

    return f"{program_name()} train --resume --output {shlex.quote(str(output))}"


def main(argv: list[str] | None = None) -> int:
    """Parse ``argv`` (default ``sys.argv[1:]``), check every setting once, run the subcommand's ``command_NAME``.

    :return: the exit status (a user error exits 2 with one line on stderr, a Ctrl-C outside training 130)
    """
    parser = build_parser()
    args = parser.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)  # as given: the sweep's resume command repeats it
    try:
        check_arguments(args)
        command = importlib.import_module(f"{__name__}.{args.command}")
        return getattr(command, f"command_{args.command}")(args)
    except USER_ERRORS as error:
        kind = "" if isinstance(error, (ValueError, TypeError)) else f"{type(error).__name__}: "
        message = " ".join(str(error).split())  # one line, whatever the library wrote
        parser.exit(2, f"sb3-latentswarm {args.command}: error: {kind}{message}\n")
    except KeyboardInterrupt:  # Ctrl-C outside training: the files finished so far are complete (atomic writes)
        print(f"\nsb3-latentswarm {args.command}: interrupted; the files it finished are kept", file=sys.stderr)
        return 130
    return 1

