"""Write the weight-only model files the tests load (``tests/data/models/``) from the committed results.

The tests read ``tests/data/``, never ``docs/results/``: a results folder can then be archived, moved or left out of
a checkout without breaking a test. Each fixture is a copy of a committed model file without its optimizer state
(``policy.optimizer.pth``, Adam's two moments: about two thirds of the file), which no test reads. Every other entry
is copied byte for byte, so a fixture keeps what its original holds, including what an older version of the package
wrote (``tests/test_actor.py`` checks that files from before the actor options existed still act as recorded) and its
weights, bit for bit (the reference episodes of ``tests/test_evaluation_reference.py`` stay the same).
``LatentSwarmPPO.save(path, include_optimizer=False)`` writes the same entries for a model of today.

Run from the repository root (the sources were removed from the tree; they are in the history):

    git checkout 206f0d5 -- docs/results/coordination/trials/proposed-seed0/model.zip docs/results/fast_1800_updates
    python examples/weight_only_models.py
    git checkout HEAD -- docs/results   # or git rm the restored files again
"""

from __future__ import annotations

import argparse
import zipfile
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SOURCE_COMMIT = "206f0d5"
"""The last commit whose tree holds the source models under ``docs/results/``."""

FIXTURES = {
    "coordination-proposed-seed0.zip": "docs/results/coordination/trials/proposed-seed0/model.zip",
    "fast_1800_updates.zip": "docs/results/fast_1800_updates/model.zip",
    "fast_1800_updates-independent_ppo.zip": "docs/results/fast_1800_updates/independent_ppo.zip",
}
"""Fixture name in ``tests/data/models/`` -> the committed model it copies (path from the repository root)."""

OPTIMIZER_ENTRIES = ("policy.optimizer.pth",)
"""The zip entries a weight-only file leaves out (what ``save(..., include_optimizer=False)`` does not write)."""


@dataclass(frozen=True)
class Args:
    output: Path = ROOT / "tests" / "data" / "models"
    """Folder the fixtures are written to."""
    source_root: Path = ROOT
    """Repository root the sources' paths are relative to (a checkout of ``SOURCE_COMMIT`` works too)."""


def weight_only_copy(source: Path, target: Path) -> None:
    """Copy the model file ``source`` to ``target`` without its optimizer state, every other entry byte for byte."""
    with zipfile.ZipFile(source) as original, zipfile.ZipFile(target, "w", zipfile.ZIP_DEFLATED) as out:
        names = [item.filename for item in original.infolist()]
        if "policy.pth" not in names or "data" not in names:
            raise SystemExit(f"{source} is not a model file (entries: {names})")
        for item in original.infolist():
            if item.filename not in OPTIMIZER_ENTRIES:
                out.writestr(item, original.read(item.filename), compress_type=zipfile.ZIP_DEFLATED)  # its date kept


def main(args: Args) -> None:
    missing = [path for path in FIXTURES.values() if not (args.source_root / path).exists()]
    if missing:
        raise SystemExit(
            f"missing source model(s) {missing}: restore them with `git checkout {SOURCE_COMMIT} -- {' '.join(missing)}`"
        )
    args.output.mkdir(parents=True, exist_ok=True)
    for name, source in FIXTURES.items():
        target = args.output / name
        weight_only_copy(args.source_root / source, target)
        size, original = target.stat().st_size, (args.source_root / source).stat().st_size
        print(f"{target}: {size:,} bytes ({size / original:.0%} of {source})")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--output", type=Path, default=Args.output, help="folder for the fixtures")
    parser.add_argument("--source-root", type=Path, default=Args.source_root, help="repository root of the sources")
    main(Args(**vars(parser.parse_args())))
