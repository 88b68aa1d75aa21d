"""mkdocs hooks for the documentation site: the pages link to repository files as GitHub shows them.

The Markdown pages are written to work on GitHub too, so they link to the shipped checkpoints' READMEs
(``../baselines/checkpoints/NAME/README.md``) and, where they include a README section, to ``docs/PAGE.md``.
Outside ``docs/`` such links have no page on the site. These hooks

* add a page ``checkpoints/NAME.md`` for every ``baselines/checkpoints/NAME/README.md`` (its text as it is);
* rewrite, in every page, a link to such a README into a link to that page, and a link ``docs/PAGE`` (from an
  included README section) into ``PAGE``.

Loaded by ``mkdocs.yml`` (``hooks:``).
"""

from __future__ import annotations

import posixpath
import re
from pathlib import Path
from typing import Any

from mkdocs.structure.files import File, Files

ROOT = Path(__file__).resolve().parent.parent
CHECKPOINTS = ROOT / "baselines" / "checkpoints"
# a Markdown link target: ](target) or ](target#anchor)
_LINK = re.compile(r"\]\((?P<target>[^)\s#]+)(?P<anchor>#[^)\s]*)?\)")


def on_files(files: Files, config: Any) -> Files:
    for readme in sorted(CHECKPOINTS.glob("*/README.md")):
        files.append(File.generated(config, f"checkpoints/{readme.parent.name}.md",
                                    content=readme.read_text(encoding="utf-8")))
    return files


def _site_target(repo_dir: str, page_dir: str, target: str) -> str | None:
    """The site page for a link ``target`` written in a file of the repository directory ``repo_dir`` and shown
    on a site page in ``page_dir``; None where the link is right as it is (a docs page to a docs page)."""
    if "://" in target or target.startswith(("mailto:", "/")):
        return None
    repo_path = posixpath.normpath(posixpath.join(repo_dir, target))
    moved = repo_path.startswith("docs/docs/")  # a README section's link (written from the root) on a docs page
    if moved:
        repo_path = repo_path[len("docs/"):]
    match = re.fullmatch(r"baselines/checkpoints/([^/]+)/README\.md", repo_path)
    if match and (CHECKPOINTS / match.group(1) / "README.md").is_file():
        site_path = f"checkpoints/{match.group(1)}.md"
    elif repo_path.startswith("docs/") and (moved or not repo_dir.startswith("docs")):
        site_path = repo_path[len("docs/"):]  # a docs page, linked from a file that is not under docs/
    else:
        return None
    return posixpath.relpath(site_path, page_dir or ".")


def on_page_markdown(markdown: str, page: Any, config: Any, files: Files) -> str:
    src = page.file.src_uri
    page_dir = posixpath.dirname(src)
    checkpoint = re.fullmatch(r"checkpoints/([^/]+)\.md", src)
    # where the page's text lives in the repository: a checkpoint's README, or the page itself under docs/
    repo_dir = f"baselines/checkpoints/{checkpoint.group(1)}" if checkpoint else posixpath.join("docs", page_dir)

    def rewrite(m: re.Match[str]) -> str:
        new = _site_target(repo_dir.rstrip("/"), page_dir, m.group("target"))
        return m.group(0) if new is None else f"]({new}{m.group('anchor') or ''})"

    return _LINK.sub(rewrite, markdown)
