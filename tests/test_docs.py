"""The documentation's generated parts: the results page built from ``docs/results/``."""

import re
import runpy
import subprocess
from pathlib import Path

import pytest

DOCS = Path(__file__).resolve().parents[1] / "docs"


def results_page() -> str:
    conf = runpy.run_path(str(DOCS / "conf.py"))
    return conf["_place_results"]((DOCS / "results.md").read_text())


def results_folders() -> list[str]:
    """The results folders on disk, as the docs build finds them: ``NAME`` (current) or ``archive/NAME``."""
    return runpy.run_path(str(DOCS / "conf.py"))["results_folders"]()


def test_results_page_places_every_folder_once_under_a_title_of_its_own():
    source = (DOCS / "results.md").read_text()
    placed = re.findall(r"^<!-- results-folder: ([\w./-]+) -->$", source, re.MULTILINE)
    assert sorted(placed) == results_folders()
    page = results_page()
    titles = re.findall(r"^#{2,3} (.+)$", page, re.MULTILINE)
    assert len(titles) == len(set(titles)), titles
    # the reports' own "# Table I run: preset `fast`" titles, alike in every folder, are left out
    assert "Table I run" not in page
    # current first: every folder the index marks current is placed before every historical one
    current, historical = results_index()
    order = [name for name in placed if name in current] + [name for name in placed if name in historical]
    assert placed == order, placed


def results_index() -> tuple[list[str], dict[str, str]]:
    """``docs/results/README.md``: the current folders in order, and each historical folder with what supersedes it."""
    text = (DOCS / "results" / "README.md").read_text()
    current_part, historical_part = text.split("\n## Current\n")[1].split("\n## Historical")
    historical_part = historical_part.split("\n## ")[0]
    row = re.compile(r"^\| `((?:archive/)?[\w.-]+)/` \|(.*)\|$", re.MULTILINE)
    current = [name for name, _ in row.findall(current_part)]
    historical = {name: rest.rsplit("|", 1)[-1] for name, rest in row.findall(historical_part)}
    return current, historical


def test_results_index_lists_every_folder_once_current_first_and_says_what_supersedes_each_historical_one():
    current, historical = results_index()
    folders = results_folders()
    listed = current + list(historical)
    assert len(listed) == len(set(listed)), "a folder is listed twice"
    assert sorted(listed) == folders, (sorted(set(folders) - set(listed)), sorted(set(listed) - set(folders)))
    text = (DOCS / "results" / "README.md").read_text()
    assert text.index("## Current") < text.index("## Historical")
    for name, superseded_by in historical.items():
        named = re.findall(r"`((?:archive/)?[\w.-]+)/`", superseded_by)
        assert named and set(named) <= set(folders), (name, superseded_by)


def test_historical_folders_without_model_files_sit_in_the_archive_and_current_ones_outside_it():
    current, historical = results_index()
    assert not [name for name in current if name.startswith("archive/")]
    for name in historical:
        holds_models = any((DOCS / "results" / name).rglob("*.zip"))
        assert name.startswith("archive/") != holds_models, f"{name}: model files {holds_models}"


def test_the_model_files_table_says_which_trials_keep_their_model_in_the_tree():
    # issue 33: a results folder keeps the models docs and tests load; the index names the commit with the others
    text = (DOCS / "results" / "README.md").read_text()
    table = text.split("<!-- model-files -->")[1].split("<!-- /model-files -->")[0]
    listed = {}
    for name, kept, commit in re.findall(r"^\| `([\w.-]+)/` \| (.*?) \| (.*) \|$", table, re.MULTILINE):
        listed[name] = set(re.findall(r"`([\w-]+-seed\d+)`", kept))
        assert re.search(r"`[0-9a-f]{40}`", commit) or "README.md" in commit, (name, commit)
    for folder in sorted((DOCS / "results").glob("*/trials")):
        trials = {p.name for p in folder.iterdir() if p.is_dir()}
        with_model = {name for name in trials if (folder / name / "model.zip").is_file()}
        if with_model != trials:
            assert folder.parent.name in listed, f"{folder.parent.name}: trials without model.zip, not in the table"
            assert listed[folder.parent.name] == with_model, folder.parent.name


def test_the_checkout_stays_light():
    # issue 33: the tracked tree is <= 60 MB (models out of the tree, per-episode tables gzipped); the history keeps
    # the rest, at the commits docs/results/README.md names
    root = DOCS.parent  # the tests run from a checkout (CI: a fresh clone), so git knows the tracked files
    listed = subprocess.run(["git", "ls-files", "-z"], cwd=root, capture_output=True, check=True).stdout
    sizes = {name: (root / name).stat().st_size for name in listed.decode().split("\0") if (root / name).is_file()}
    total = sum(sizes.values())
    biggest = sorted(sizes, key=sizes.get)[-5:]
    assert total <= 60_000_000, f"tracked files weigh {total:,} bytes (> 60 MB); the biggest: {biggest}"
    assert not [name for name in sizes if name.endswith("/episodes.csv") and "/trials/" in name], "gzip trial tables"


def test_every_condition_and_link_model_has_its_row_in_the_tables_that_describe_them():
    # issue 33's new-contributor trial: a condition or link model added in code must reach the tables people read
    from sb3_latentswarm.config import LINK_MODELS
    from sb3_latentswarm.evaluation import CONDITION_TABLE, conditions
    from sb3_latentswarm.links import __doc__ as links_doc

    evaluation_page = (DOCS / "evaluation.md").read_text()
    for name in CONDITION_TABLE:
        assert f"``{name}``" in conditions.__doc__, f"{name}: no row in evaluation/conditions.py's docstring table"
        assert f"| `{name}`" in evaluation_page, f"{name}: no row in docs/evaluation.md's conditions table"
    concepts = (DOCS / "concepts.md").read_text()
    for name in LINK_MODELS:
        assert f'link_model="{name}"' in links_doc, f"{name}: not in links/__init__.py's docstring"
        assert f'`link_model="{name}"`' in concepts or f'`"{name}"`' in concepts, f"{name}: not in docs/concepts.md"


def test_every_results_plot_has_a_caption():
    page = results_page()
    figures = re.findall(r"```\{figure\} (\S+)\n:alt: \S+\n\n(.+)\n```", page)
    images = [p for name in results_folders() for p in (DOCS / "results" / name).glob("*") if p.suffix in (".png", ".gif")]
    assert len(figures) == len(images) > 0
    assert all(caption.strip() for _, caption in figures)
    assert "{image}" not in page
    # each caption says what the plot shows and from which run; no two captions alike
    assert all("Run: `docs/results/" in caption for _, caption in figures)
    assert len({caption for _, caption in figures}) == len(figures)


def test_results_figures_are_legible_at_page_width():
    from PIL import Image

    for path in sorted(p for name in results_folders() for p in (DOCS / "results" / name).glob("*.png")):
        width, height = Image.open(path).size
        assert width <= 1600 and width <= 3.5 * height, f"{path.name}: {width} x {height} px"


def test_results_page_keeps_long_reports_collapsed():
    page = results_page()
    # the folders' reports and plots sit in <details> blocks, so the page reads as its own text and the claims
    folders = re.findall(r"^<!-- results-folder: ", (DOCS / "results.md").read_text(), re.MULTILINE)
    assert page.count("<details>") == page.count("</details>") >= len(folders) > 0
    outside = re.sub(r"<details>.*?</details>", "", page, flags=re.S)
    assert outside.count("\n|") < 60  # table rows left open: the claims table and a few short ones


@pytest.mark.slow  # builds the whole site with Sphinx: 15 s at load 5 (`make docs` in CI builds it too)
def test_built_pages_are_offline_readable_and_show_no_inherited_torch_docstring(tmp_path):
    import subprocess
    import sys

    build = subprocess.run(
        [sys.executable, "-m", "sphinx", "-q", "-W", "--keep-going", "-b", "html", str(DOCS), str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert build.returncode == 0, build.stderr
    algorithm = (tmp_path / "algorithm.html").read_text()
    # LatentSwarmPolicy.__init__ has no docstring: torch's "Initialize internal Module state" must not stand in
    assert "Initialize internal Module state" not in algorithm
    # maths: MathJax from the build itself, no CDN
    assert '<script defer="defer" src="_static/mathjax/tex-chtml.js">' in algorithm
    assert (tmp_path / "_static" / "mathjax" / "tex-chtml.js").exists()
    assert not any("cdn.jsdelivr.net" in page.read_text() for page in tmp_path.glob("*.html"))
    # wide tables wrap instead of being cut off by the theme's nowrap
    assert '<link rel="stylesheet" type="text/css" href="_static/custom.css' in algorithm
    assert "white-space: normal" in (tmp_path / "_static" / "custom.css").read_text()


def test_package_docstrings_point_only_inside_the_repository():
    package = DOCS.parent / "sb3_latentswarm"
    offenders = [p for p in package.rglob("*.py") if "/work/" in p.read_text() or "/tmp/" in p.read_text()]
    assert offenders == []
