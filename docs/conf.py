"""Sphinx configuration of the sb3-latentswarm documentation (Sphinx + MyST, as Stable-Baselines3).

Build (the CI check): ``sphinx-build -W --keep-going -b html docs docs/_build/html``. The build and the built pages
are offline: no intersphinx inventories are fetched, the package is imported from the installed (editable) checkout,
and MathJax is copied into the build by ``sphinx-mathjax-offline`` instead of being loaded from a CDN.
"""

from __future__ import annotations

import inspect
import os
import re
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, os.path.abspath(".."))

from sphinx.util import logging  # noqa: E402

from sb3_latentswarm.version import __version__  # noqa: E402

logger = logging.getLogger(__name__)

project = "sb3-latentswarm"
author = "sb3-latentswarm contributors"
copyright = "2026, sb3-latentswarm contributors"
version = __version__
release = __version__

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.mathjax",
    "sphinx-mathjax-offline",  # a local copy of MathJax 3 in _static/mathjax: the pages render maths offline
    "myst_parser",
]

source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
root_doc = "index"
# docs/results/ is filled by examples/reproduce_table1.py; its files are pulled into results.md (see below), not
# built as pages of their own.
exclude_patterns = ["_build", "Thumbs.db", ".DS_Store", "results", "results/**"]

myst_enable_extensions = ["dollarmath", "colon_fence", "deflist"]
myst_heading_anchors = 3

autodoc_member_order = "bysource"
autodoc_typehints = "description"
autodoc_typehints_description_target = "documented_params"
autodoc_default_options = {"show-inheritance": True, "exclude-members": "__new__"}
autodoc_class_signature = "separated"

html_theme = "sphinx_rtd_theme"
html_title = f"sb3-latentswarm {__version__}"
html_theme_options = {"navigation_depth": 3}
html_static_path = ["_static"]
html_css_files = ["custom.css"]  # wide tables wrap instead of being cut off


# ---------------------------------------------------------------------------------------------- results
DOCS_DIR = Path(__file__).resolve().parent
RESULTS_DIR = DOCS_DIR / "results"
# historical folders without a model file sit in docs/results/archive/ (docs/results/README.md, the folders' index)
ARCHIVE = "archive"
IMAGE_SUFFIXES = (".png", ".svg", ".gif", ".jpg")
DATA_SUFFIXES = (".csv", ".json", ".txt", ".pdf")
# results.md places each results folder with a line `<!-- results-folder: NAME -->` under a heading of its own, so the
# page's order and titles are chosen by its author, not by the folders' alphabetical order.
RESULTS_MARKER = re.compile(r"^<!-- results-folder: ((?:archive/)?[\w.-]+) -->$", re.MULTILINE)
# What each plot that the scripts write shows; the first sentence of its caption in results.md (the second names the
# run it comes from: the folder and the heading of its section).
PLOT_CAPTIONS = {
    "resume_learning_curve": "Coverage and collisions of the training rollouts against agent-steps of a run killed with "
    "kill -9 after 13 updates and resumed with train --resume (seed 1), beside a run that never stopped (seed 2).",
    "coverage_vs_time": "Mean coverage (%) against the episode's step under each condition of Table I, p_f = 0.3.",
    "coverage_vs_p_fail": "Final coverage (%) against the link failure probability p_f (proposed model), next to the "
    "paper's Table I (right).",
    "learning_curve": "Mean final coverage (%) against PPO updates under each condition, with mean and sampled "
    "actions; bands are 95 % confidence intervals of the mean.",
    "learning_curves": "Coverage of finished training episodes and episode return against agent-steps, per learner: "
    "mean across training seeds with a 95 % bootstrap band.",
    "intervals_coverage": "Final coverage (%) per evaluation set, condition and learner: IQM across training seeds with "
    "95 % stratified-bootstrap intervals.",
    "intervals_collisions": "Collisions per episode per evaluation set, condition and learner: IQM across training seeds "
    "with 95 % stratified-bootstrap intervals.",
    "intervals_steps_to_90": "Steps to 90 % coverage (episodes that reach it) per evaluation set, condition and learner: "
    "IQM across training seeds with 95 % stratified-bootstrap intervals.",
    "intervals_reached_90": "Share of episodes reaching 90 % coverage per evaluation set, condition and learner: IQM "
    "across training seeds with 95 % stratified-bootstrap intervals.",
    "episode": "One evaluation episode (proposed condition): the UAVs, their links and the coverage map (since 0.2.0 a "
    "legend beside the map names every colour, the condition, the episode seed and the way of acting).",
    "episode_trajectories": "The UAVs' trajectories in that episode (o: start, x: a UAV in dropout).",
}
# results.md places a figure itself (the claims' figures) with a MyST figure directive; the folder then leaves it out.
FIGURE_DIRECTIVE = re.compile(r"^```\{figure\} (\S+)$", re.MULTILINE)
HEADING = re.compile(r"^(#{1,6}) (.+)$", re.MULTILINE)


def _report_text(path: Path) -> list[str]:
    """A folder's ``run.md`` (or other markdown) inlined in a collapsed section: without its ``#`` title (alike in
    every folder), headings as bold lines (a section inside a ``<details>`` block would break the page's outline),
    and without its image lines (the folder's plots are placed as captioned figures)."""
    lines = path.read_text(encoding="utf-8").splitlines()
    if lines and lines[0].startswith("# "):
        lines = lines[1:]
    out = []
    for line in lines:
        if line.startswith("!["):
            continue
        heading = HEADING.match(line)
        out.append(f"**{heading.group(2)}**" if heading else line)
    return out


def _collapsed(summary: str, body: list[str]) -> list[str]:
    # MyST passes the HTML through; the blank lines let the markdown between the tags be parsed as markdown
    return ["<details>", f"<summary>{summary}</summary>", "", *body, "", "</details>", ""]


def _results_folder(folder: Path, section: str, placed_images: set[str]) -> list[str]:
    """MyST for one ``docs/results/<run>/`` folder, under the heading ``section`` that ``results.md`` writes.

    The folder's report (``run.md``, which holds its tables; a folder without one: each markdown file) and its plots
    (a figure each, captioned with what it shows and from which run) are collapsed sections, so that the page reads
    as the claims and the text of ``results.md``; the data files are download links. Anything else (``model.zip``) is
    left out, and so are the images that ``results.md`` places itself.
    """
    files = sorted(p for p in folder.iterdir() if p.is_file())
    markdown = [p for p in files if p.suffix.lower() == ".md" and p.name.lower() != "readme.md"]
    rel = folder.relative_to(DOCS_DIR).as_posix()
    name = folder.relative_to(RESULTS_DIR).as_posix()
    images = [p for p in files if p.suffix.lower() in IMAGE_SUFFIXES and f"{rel}/{p.name}" not in placed_images]
    data = [p for p in files if p.suffix.lower() in DATA_SUFFIXES]
    if folder / "run.md" in markdown:
        markdown = [folder / "run.md"]
    parts: list[str] = []
    if data:
        parts += ["Data: " + ", ".join(f"{{download}}`{path.name} <{rel}/{path.name}>`" for path in data), ""]
    body = [line for path in markdown for line in [*_report_text(path), ""]]
    if body:
        names = " and ".join(f"<code>{path.name}</code>" for path in markdown)
        parts += _collapsed(f"Report and tables ({names} of <code>docs/results/{name}/</code>)", body)
    figures: list[str] = []
    for path in images:
        what = PLOT_CAPTIONS.get(path.stem, path.stem.replace("_", " ").capitalize() + ".")
        caption = f"{what} Run: `docs/results/{name}/` ({section})."
        figures += [f"```{{figure}} {rel}/{path.name}", f":alt: {path.stem}", "", caption, "```", ""]
    if figures:
        parts += _collapsed(f"Figures ({len(images)})", figures)
    return parts


def results_folders() -> list[str]:
    """Every results folder, relative to ``docs/results/``: ``NAME`` for a current one, ``archive/NAME`` for an archived
    one."""

    def folders(parent: Path) -> list[Path]:
        return [p for p in parent.iterdir() if p.is_dir() and not p.name.startswith((".", "_"))]

    archived = [f"{ARCHIVE}/{p.name}" for p in folders(RESULTS_DIR / ARCHIVE)] if (RESULTS_DIR / ARCHIVE).is_dir() else []
    return sorted([p.name for p in folders(RESULTS_DIR) if p.name != ARCHIVE] + archived)


def _place_results(text: str) -> str:
    """Replace each results marker of ``results.md`` by its folder; a folder no marker places is a build warning."""
    placed = set(RESULTS_MARKER.findall(text))
    present = results_folders()
    for name in sorted(placed - set(present)):
        logger.warning("results.md places docs/results/%s/, which does not exist", name, location="results")
    for name in sorted(set(present) - placed):
        logger.warning(
            "docs/results/%s/ is not on the results page: add a heading and `<!-- results-folder: %s -->` to results.md",
            name,
            name,
            location="results",
        )
    placed_images = set(FIGURE_DIRECTIVE.findall(text))

    def section(match: re.Match) -> str:
        folder = RESULTS_DIR / match.group(1)
        headings = HEADING.findall(text[: match.start()])
        title = headings[-1][1] if headings else folder.name
        return "\n".join(_results_folder(folder, title, placed_images)) if folder.is_dir() else ""

    return RESULTS_MARKER.sub(section, text)


def _append_results(app, docname: str, source: list[str]) -> None:
    if docname == "results":
        source[0] = _place_results(source[0])


# ---------------------------------------------------------------------------------------------- presets
PRESETS_MARKER = "<!-- presets-table -->"


def _learning_rate_text(learning_rate) -> str:
    from sb3_latentswarm.latent_ppo.schedules import StepSchedule

    def number(value: float) -> str:
        return np.format_float_scientific(value, trim="-", exp_digits=1)

    if isinstance(learning_rate, StepSchedule):
        return (
            f"{number(learning_rate.initial_value)}, then {number(learning_rate.final_value)} after "
            f"{learning_rate.switch_fraction:.1%} of training"
        )
    return f"{number(learning_rate)}, constant"


def presets_table() -> str:
    """The table of ``sb3_latentswarm.presets.PRESETS``, generated from the code so that it cannot drift."""
    from sb3_latentswarm.latent_ppo import LatentSwarmPolicy, LatentSwarmPPO
    from sb3_latentswarm.presets import PRESETS

    algo_defaults = {name: p.default for name, p in inspect.signature(LatentSwarmPPO.__init__).parameters.items()}
    policy_defaults = {name: p.default for name, p in inspect.signature(LatentSwarmPolicy.__init__).parameters.items()}
    presets = list(PRESETS.values())

    def algo(preset, *keys: str) -> str:
        return ", ".join(str(preset.algo_kwargs.get(key, algo_defaults[key])) for key in keys)

    def policy(preset, *keys: str) -> str:
        kwargs = preset.algo_kwargs.get("policy_kwargs", {})
        return ", ".join(str(kwargs.get(key, policy_defaults[key])) for key in keys)

    def horizon(preset) -> str:
        c = preset.config
        budget = f"{c.initial_energy / c.energy_decay:g}" if c.energy_decay > 0 else "never"
        return f"{c.max_steps}; {budget}"

    def motion(preset) -> str:
        c = preset.config
        return f"{c.v_max:g} m/s, {c.vz_max:g} m/s, {c.d_safe:g} m"

    rows = {
        "grid (cells), cell size": lambda p: f"{p.config.grid_width} x {p.config.grid_height}, {p.config.cell_size:g} m",
        "$N$ (`n_agents`)": lambda p: f"{p.config.n_agents}",
        "$T$ (`max_steps`); $b_0 / \\kappa$": horizon,
        "`num_obstacles`": lambda p: f"{p.config.num_obstacles}",
        "`v_max`, `vz_max`, `d_safe`": motion,
        "`start_region`; `outage_model`": lambda p: f"{p.config.start_region}; {p.config.outage_model}",
        "swarms (`n_envs`)": lambda p: f"{p.n_envs}",
        "`n_steps`, `chunk_length`, `batch_size`, `n_epochs`": lambda p: algo(
            p, "n_steps", "chunk_length", "batch_size", "n_epochs"
        ),
        "`latent_dim`": lambda p: policy(p, "latent_dim"),
        "predictor, decoder, critic, actor widths": lambda p: policy(
            p, "predictor_hidden", "decoder_hidden", "critic_hidden", "actor_hidden"
        ),
        "learning rate": lambda p: _learning_rate_text(p.algo_kwargs.get("learning_rate", algo_defaults["learning_rate"])),
        "training agent-steps (updates)": lambda p: f"{p.total_timesteps:,} ({p.updates:,})",
        "evaluation episodes per condition": lambda p: f"{p.eval_episodes}",
    }
    lines = ["| | " + " | ".join(f"`{p.name}`" for p in presets) + " |", "|---|" + "---|" * len(presets)]
    lines += [f"| {label} | " + " | ".join(cell(p) for p in presets) + " |" for label, cell in rows.items()]
    return "\n".join(lines)


def _insert_presets_table(app, docname: str, source: list[str]) -> None:
    if PRESETS_MARKER in source[0]:
        source[0] = source[0].replace(PRESETS_MARKER, presets_table())


def _always_reread(app, env, added, changed, removed) -> list[str]:
    # Their content comes from outside docs/ (the code, docs/results/): re-read them on every incremental build too.
    return ["concepts", "results"]


def _drop_inherited_init_docstring(app, what: str, name: str, obj, options, lines: list[str]) -> None:
    """An ``__init__`` without a docstring of its own would show its base's (torch's ``Module.__init__``): the
    class docstring documents the parameters, so the ``__init__`` entry keeps only its signature."""
    if name.endswith(".__init__") and getattr(obj, "__doc__", None) is None:
        lines.clear()


def setup(app):
    app.connect("autodoc-process-docstring", _drop_inherited_init_docstring)
    app.connect("source-read", _append_results)
    app.connect("source-read", _insert_presets_table)
    app.connect("env-get-outdated", _always_reread)
    return {"parallel_read_safe": True}
