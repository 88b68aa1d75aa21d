"""The documentation: every relative link resolves, and the site builds with warnings as errors.

The site is mkdocs (``mkdocs.yml``; the ``docs`` extra, also in ``dev``): ``mkdocs build --strict``
fails on a docstring whose ``Args:`` do not match its signature, a missing page in the nav's
targets, a broken anchor, or a README section marker that went missing.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = sorted([ROOT / "README.md", *(ROOT / "docs").rglob("*.md"), *(ROOT / "baselines" / "checkpoints").rglob("*.md")])
# [text](target) outside code spans; images included. Targets with a scheme or a bare anchor are not files.
LINK = re.compile(r"\]\(([^)\s]+)\)")


def _links(page: Path) -> list[str]:
    text = re.sub(r"```.*?```", "", page.read_text(encoding="utf-8"), flags=re.S)  # code blocks hold no links
    text = re.sub(r"`[^`\n]*`", "", text)
    return [t for t in LINK.findall(text) if not re.match(r"[a-z][a-z0-9+.-]*:|#", t)]


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_resolve(page: Path) -> None:
    broken = [t for t in _links(page) if not (page.parent / t.split("#", 1)[0]).exists()]
    assert not broken, f"{page.relative_to(ROOT)} links to missing files: {broken}"


def test_link_checker_sees_links() -> None:
    # The checker must find the README's links to docs/ (otherwise the test above checks nothing).
    assert any(t.startswith("docs/") for t in _links(ROOT / "README.md"))


@pytest.mark.slow
def test_site_builds_strict(tmp_path: Path) -> None:
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    proc = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    html = (tmp_path / "site" / "api" / "core" / "index.html").read_text(encoding="utf-8")
    assert "swarm_env.sim.world" in html and "doc-function" in html  # the API reference was generated
    env_page = (tmp_path / "site" / "environment" / "index.html").read_text(encoding="utf-8")
    assert "OBS_OWN_TWIST" in env_page  # the README section was included
    site = tmp_path / "site"
    for page in (site / "api").glob("*/index.html"):  # the docstrings' Sphinx markup was made Markdown
        text = page.read_text(encoding="utf-8")
        assert not re.search(r":(class|func|meth|mod|data|attr):`", text) and ".. code-block::" not in text, page
    home = (site / "index.html").read_text(encoding="utf-8")
    assert "Install and quick start" in home and "paper_vo_45" in home and "parallel_env" in home  # README blocks
    baselines = (site / "baselines" / "index.html").read_text(encoding="utf-8")
    for name in ("ippo", "mappo", "residual_vo", "sb3_ppo"):  # the checkpoints' READMEs are pages of the site
        assert f'href="../checkpoints/{name}/"' in baselines and (site / "checkpoints" / name / "index.html").is_file()
