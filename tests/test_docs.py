"""What a newcomer reads first says what the product is: the package's docstring, ``bimscan --help``
and the documentation's home page name every part of it and lead to every guide."""

from __future__ import annotations

import re
from pathlib import Path

import bimscan
from bimscan.cli.main import main

ROOT = Path(__file__).parents[1]
# each part of the product, in words a first page must use for it (issue 50: "terrestrial laser scans" only)
PARTS = {"tripod": r"tripod|TLS", "mobile": r"mobile|handheld", "survey planning": r"plan",
         "datasets": r"dataset", "training": r"train", "adaptation": r"adapt",
         "scan against model": r"built"}


def _missing(text: str) -> list[str]:
    return [part for part, words in PARTS.items() if not re.search(words, text, flags=re.I)]


def test_the_package_docstring_names_every_part_of_the_product():
    assert _missing(bimscan.__doc__ or "") == []
    for package in ("ifc", "semantics", "site", "scan", "survey", "planning", "process", "io", "dataset", "stats",
                    "render", "learn", "compare", "cli", "pipeline"):
        assert f"``{package}``" in (bimscan.__doc__ or ""), package


def test_bimscan_help_names_every_part_of_the_product(capsys):
    assert main(["--help"]) == 0
    summary = capsys.readouterr().out.split("Options:")[0]
    assert _missing(summary) == []


def test_the_home_page_names_every_part_and_links_every_guide_page_of_the_site():
    home = (ROOT / "docs" / "index.md").read_text(encoding="utf-8")
    assert _missing(home.split("## Where to start")[0]) == []
    guides = re.findall(r"\b(guide/[\w-]+\.md)", (ROOT / "mkdocs.yml").read_text(encoding="utf-8"))
    assert len(guides) >= 15
    assert [page for page in guides if f"({page}" not in home] == []


def test_the_python_guide_maps_every_module_and_subpackage_of_the_package():
    guide = (ROOT / "docs" / "guide" / "python.md").read_text(encoding="utf-8")
    package = ROOT / "src" / "bimscan"
    names = [p.stem for p in package.glob("*.py") if p.stem != "__init__"]
    names += [p.name for p in package.iterdir() if (p / "__init__.py").is_file()]
    names += ["planning", "multibeam", "platform", "walk", "adapt", "predict"]
    assert [name for name in names if not re.search(rf"\b{name}\b", guide)] == []
