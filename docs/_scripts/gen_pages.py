"""Pages generated at each build (mkdocs-gen-files), so nothing here is kept by hand.

- ``reference/``: one page per module of ``numeric/`` and ``service/`` found on disk at
  build time (a package's page is its ``index.md``), each a mkdocstrings ``:::``
  directive, with its own literate-nav ``SUMMARY.md`` in the package tree's order.
- ``http-api/``: ``openapi.json`` from ``chizu.service.app.create_app()`` and its rendering
  (:mod:`openapi_page`).
- ``results/index.md`` (unless one is written by hand): the results pages that
  ``make bench`` wrote, with the command, date and commit of each.
- ``SUMMARY.md``: the site's navigation. Home, then one section per folder of ``docs/``
  holding Markdown pages (tutorials, notes, results first, any other folder after), each
  page titled by its first heading, then the HTTP API and the API reference.
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import mkdocs_gen_files

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
DOCS = ROOT / "docs"
PACKAGES = ("numeric", "service")
#: the sections that come first, in this order, with their titles; other folders follow
SECTIONS = {"tutorials": "Tutorials", "notes": "Notes", "results": "Results"}
#: folders of docs/ that hold no pages of their own
NOT_SECTIONS = {"_scripts", "figures", "reference", "http-api"}

sys.path.insert(0, str(HERE))
from openapi_page import render  # noqa: E402


def title_of(text: str, fallback: str) -> str:
    """A page's first level-1 heading (Markdown emphasis and code marks removed)."""
    m = re.search(r"^#\s+(.+?)\s*#*\s*$", text, re.MULTILINE)
    title = re.sub(r"[`*_]", "", m.group(1)).strip() if m else fallback
    return title.replace("[", "(").replace("]", ")")  # brackets would end the nav's link


def reference_pages() -> None:
    """``reference/<package path>.md`` for every module, and their navigation."""
    nav = mkdocs_gen_files.Nav()
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            if "__pycache__" in parts or parts[-1] == "__main__":
                continue
            if parts[-1] == "__init__":
                parts = parts[:-1]
                doc = Path("reference", *parts, "index.md")
            else:
                doc = Path("reference", *parts).with_suffix(".md")
            nav[parts] = doc.relative_to("reference").as_posix()
            with mkdocs_gen_files.open(doc, "w") as f:
                f.write(f"::: chizu.{'.'.join(parts)}\n")
    with mkdocs_gen_files.open("reference/index.md", "w") as f:
        f.write("# API reference\n\nEvery module of `chizu.numeric` (the numeric plugins: "
                "no HTTP, no Prolog; the folder `numeric/`) and `chizu.service` (the FastAPI "
                "service, the CLI and the Prolog bridge; `service/`), generated from the "
                "docstrings at build time.\n\n"
                + "".join(f"- [`{p}`]({p}/index.md)\n" for p in PACKAGES))
    with mkdocs_gen_files.open("reference/SUMMARY.md", "w") as f:
        f.write("* [API reference](index.md)\n")
        f.writelines(nav.build_literate_nav())


def http_api_page() -> None:
    """``http-api/openapi.json`` and ``http-api/index.md`` from the app's schema."""
    from chizu.service.app import create_app

    spec = create_app().openapi()
    with mkdocs_gen_files.open("http-api/openapi.json", "w") as f:
        json.dump(spec, f, indent=1)
    with mkdocs_gen_files.open("http-api/index.md", "w") as f:
        f.write(render(spec))


def header_field(text: str, name: str) -> str:
    """The value of row ``name`` of a results page's header table (tests/bench/results.py)."""
    m = re.search(rf"^\|\s*{name}\s*\|\s*(.*?)\s*\|\s*$", text, re.MULTILINE)
    return m.group(1) if m else ""


def results_index(pages: list[Path]) -> None:
    """``results/index.md``: one row per results page."""
    rows = []
    for p in pages:
        text = p.read_text()
        rows.append(f"| [{title_of(text, p.stem)}]({p.name}) | {header_field(text, 'command')} "
                    f"| {header_field(text, 'date')} | {header_field(text, 'commit')} |")
    with mkdocs_gen_files.open("results/index.md", "w") as f:
        f.write("# Results\n\nWhat the benchmarks of `tests/bench/` measured, one page per "
                "script. `make bench` runs them all and rewrites these pages; each page names "
                "the command that wrote it (some were run in a quick mode), the date, the "
                "commit and the machine. The pages are never edited by hand: to change one, "
                "change its script and run its command again.\n\n"
                "| page | command | date | commit |\n|---|---|---|---|\n" + "\n".join(rows)
                + "\n")


def section(folder: Path) -> list[str]:
    """The navigation lines of one folder of ``docs/``: its index first, then its pages."""
    pages = sorted(p for p in folder.glob("*.md") if p.name != "index.md")
    if folder.name == "results" and not (folder / "index.md").exists():
        results_index(pages)
    title = SECTIONS.get(folder.name, folder.name.replace("-", " ").capitalize())
    has_index = (folder / "index.md").exists() or folder.name == "results"
    head = f"* [{title}]({folder.name}/index.md)" if has_index else f"* {title}"
    return [head] + [f"    * [{title_of(p.read_text(), p.stem)}]({folder.name}/{p.name})"
                     for p in pages]


def summary() -> None:
    """The site's navigation (literate-nav)."""
    lines = ["* [Home](index.md)"]
    lines += [f"* [{title_of(p.read_text(), p.stem)}]({p.name})"
              for p in sorted(DOCS.glob("*.md")) if p.name not in ("index.md", "SUMMARY.md")]
    folders = [d for d in DOCS.iterdir() if d.is_dir() and d.name not in NOT_SECTIONS
               and any(d.glob("*.md"))]
    if DOCS / "results" not in folders:  # before the first `make bench`: the index alone
        folders.append(DOCS / "results")
    order = list(SECTIONS)
    for d in sorted(folders, key=lambda d: (order.index(d.name) if d.name in order
                                            else len(order), d.name)):
        lines += section(d)
    lines += ["* [HTTP API](http-api/index.md)", "* [API reference](reference/)"]
    with mkdocs_gen_files.open("SUMMARY.md", "w") as f:
        f.write("\n".join(lines) + "\n")


reference_pages()
http_api_page()
summary()
