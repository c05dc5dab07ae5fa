"""The documentation's generated parts: the results page built from ``docs/results/``."""

import re
import runpy
from pathlib import Path

DOCS = Path(__file__).resolve().parents[1] / "docs"


def results_page() -> str:
    conf = runpy.run_path(str(DOCS / "conf.py"))
    return conf["_place_results"]((DOCS / "results.md").read_text())


def test_results_page_places_every_folder_once_under_a_title_of_its_own():
    source = (DOCS / "results.md").read_text()
    placed = re.findall(r"^<!-- results-folder: ([\w.-]+) -->$", source, re.MULTILINE)
    folders = sorted(p.name for p in (DOCS / "results").iterdir() if p.is_dir())
    assert sorted(placed) == folders
    page = results_page()
    titles = re.findall(r"^#{2,3} (.+)$", page, re.MULTILINE)
    assert len(titles) == len(set(titles)), titles
    # the reports' own "# Table I run: preset `fast`" titles, alike in every folder, are left out
    assert "Table I run" not in page
    # newest first: the short-rollout run above the 1800-update run, the 300-update checkpoint last
    assert placed.index("fast_short_rollouts") < placed.index("fast_1800_updates") < placed.index("fast")
    assert placed[-1] == "fast"


def test_every_results_plot_has_a_caption():
    page = results_page()
    figures = re.findall(r"```\{figure\} (\S+)\n:alt: \S+\n\n(.+)\n```", page)
    images = sorted(p for p in (DOCS / "results").glob("*/*") if p.suffix in (".png", ".gif"))
    assert len(figures) == len(images) > 0
    assert all(caption.strip() for _, caption in figures)
    assert "{image}" not in page
