"""MkDocs hooks of chizu's site (``hooks:`` in mkdocs.yml).

The generated navigation files (``SUMMARY.md``) are not published as pages, and two
rewrites of the Markdown before MkDocs sees it make the sources read well both on the
site and where they live:

- Sphinx roles in docstrings (``:func:`run_log```, ``:class:`~chizu.numeric.scan.Scan```)
  become code spans (``run_log``, ``Scan``); the API reference renders docstrings as
  Markdown, where a role would show as literal text.
- A relative link in a page that points into the repository outside ``docs/`` (a source
  file, the README) has no page on the site. A link to a module of ``numeric/`` or
  ``service/`` becomes a link to its API reference page, one to ``README.md`` a link to
  the home page, and one to any other existing file (a bench script, the Makefile) its
  path as a code span. A link written relative to the repository root, as the README
  writes them (``docs/figures/x.png``), is pointed at the same file from the page. A
  link whose target exists nowhere is left alone, so that ``mkdocs build --strict``
  fails on it.
"""

from __future__ import annotations

import logging
import os
import posixpath
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

from markdown import Extension, Markdown
from markdown.preprocessors import Preprocessor
from mkdocs.plugins import event_priority
from mkdocs.structure.files import InclusionLevel

log = logging.getLogger("mkdocs.hooks.chizu")

ROOT = Path(__file__).resolve().parents[2]
#: ``:role:`target``` and ``:py:role:`target``` (the Sphinx Python domain's roles)
ROLE = re.compile(r":(?:py:)?(?:func|class|mod|meth|attr|data|obj|exc|const|ref):`(~?)([^`]+)`")
#: an inline link or image: ``[text](target)`` or ``![alt](target "title")``
LINK = re.compile(r"(!?\[[^\]\n]*\])\(([^)\s]+)(\s+\"[^\"]*\")?\)")
FENCE = re.compile(r"^\s*(```|~~~)")
REFERENCED = ("numeric", "service")


def role_to_code(match: re.Match[str]) -> str:
    """``:func:`x.y``` -> ```x.y```; with Sphinx's ``~``, the last component only."""
    tilde, target = match.group(1), match.group(2)
    return f"`{target.rsplit('.', 1)[-1] if tilde else target}`"


class _RolesPreprocessor(Preprocessor):
    def run(self, lines: list[str]) -> list[str]:
        return [ROLE.sub(role_to_code, line) for line in lines]


class SphinxRoles(Extension):
    """Python-Markdown extension: Sphinx roles as code spans (see the module docstring)."""

    def extendMarkdown(self, md: Markdown) -> None:  # noqa: N802 (Markdown's API)
        md.preprocessors.register(_RolesPreprocessor(md), "chizu_sphinx_roles", 40)


#: the installed names' tree: build/namespace/chizu/numeric -> numeric/ (and service/),
#: so that mkdocstrings finds chizu.numeric.x as a user imports it (mkdocs.yml's paths)
NAMESPACE = ROOT / "build" / "namespace" / "chizu"


def link_installed_names() -> None:
    """``build/namespace/chizu/<folder>`` as symbolic links to the repository's folders."""
    NAMESPACE.mkdir(parents=True, exist_ok=True)
    for folder in REFERENCED:
        link = NAMESPACE / folder
        if not link.is_symlink():
            link.symlink_to(Path("..", "..", "..", folder))


@event_priority(100)  # before mkdocstrings copies the extension list for its docstrings
def on_config(config: Any) -> Any:
    config.markdown_extensions.append(SphinxRoles())
    link_installed_names()
    return config


@event_priority(-100)  # after gen-files has written the navigation files
def on_files(files: Any, config: Any) -> Any:
    """The literate-nav navigation files are read, not published as pages."""
    for f in files:
        if posixpath.basename(f.src_uri) == "SUMMARY.md":
            f.inclusion = InclusionLevel.EXCLUDED
    return files


def _outside_target(target: str, page_src: str, docs_dir: Path,
                    on_site: Callable[[str], bool]) -> str | None:
    """What a relative link ``target`` of page ``page_src`` should become (see the module
    docstring), or ``None`` to leave it as it is."""
    path, _, fragment = target.partition("#")
    if not path or re.match(r"^[a-zA-Z][a-zA-Z0-9+.-]*:", path) or path.startswith("/"):
        return None  # an anchor, a URL, or site-absolute
    page_dir = posixpath.dirname(page_src)
    if on_site(posixpath.normpath(posixpath.join(page_dir, path))):
        return None  # a page or file of the site (generated ones too): MkDocs checks it
    anchor = f"#{fragment}" if fragment else ""
    in_repo = (docs_dir / page_dir / path).resolve()
    if in_repo.is_relative_to(docs_dir) or not in_repo.exists():
        in_repo = (ROOT / path).resolve()  # written from the repository root
    if not in_repo.exists() or not in_repo.is_relative_to(ROOT):
        return None  # broken: --strict reports it
    if in_repo.is_relative_to(docs_dir):
        return os.path.relpath(in_repo, docs_dir / page_dir).replace(os.sep, "/") + anchor
    rel = in_repo.relative_to(ROOT)
    if rel.as_posix() == "README.md":
        return os.path.relpath(docs_dir / "index.md", docs_dir / page_dir) + anchor
    if rel.parts[0] in REFERENCED and rel.suffix == ".py":
        parts = rel.with_suffix("").parts
        page = ("reference", *parts[:-1], "index.md") if parts[-1] == "__init__" else \
            ("reference", *parts[:-1], parts[-1] + ".md")
        return os.path.relpath(docs_dir.joinpath(*page), docs_dir / page_dir)
    return "`" + rel.as_posix() + "`"


def rewrite_links(markdown: str, page_src: str, docs_dir: Path,
                  on_site: Callable[[str], bool]) -> str:
    """The page's Markdown with its links out of ``docs/`` rewritten, fenced code kept."""
    out, fenced = [], False
    for line in markdown.split("\n"):
        if FENCE.match(line):
            fenced = not fenced
        if not fenced and "](" in line:
            def fix(m: re.Match[str]) -> str:
                new = _outside_target(m.group(2), page_src, docs_dir, on_site)
                if new is None:
                    return m.group(0)
                log.debug("%s: link %s -> %s", page_src, m.group(2), new)
                if new.startswith("`"):  # no page to link: the text, then the path
                    text = m.group(1).lstrip("!")[1:-1]
                    return f"{text} ({new})" if text and text != new.strip("`") else new
                return f"{m.group(1)}({new}{m.group(3) or ''})"

            line = LINK.sub(fix, line)
        out.append(line)
    return "\n".join(out)


def on_page_markdown(markdown: str, page: Any, config: Any, files: Any) -> str:
    return rewrite_links(markdown, page.file.src_uri, Path(config.docs_dir).resolve(),
                         lambda uri: files.get_file_from_path(uri) is not None)
