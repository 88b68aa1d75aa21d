"""A griffe extension for the documentation site: the docstrings' Sphinx markup as Markdown.

The project's docstrings are written for readers of the source and of ``help()``, with Sphinx's inline roles
(``:class:`~swarm_env.env.SwarmEnv```, ``:func:``, ``:meth:``, ``:mod:``, ``:data:``, ``:attr:``, ``:exc:``)
and ``.. code-block:: LANG`` directives. mkdocstrings renders docstrings as Markdown, where both showed as
plain text. Before rendering, this extension rewrites each docstring:

* a role becomes inline code: ``:class:`~a.b.C``` shows ``C`` (the ``~`` form shows the last name, as Sphinx
  does), ``:func:`a.b.f``` shows ``a.b.f``; ``:func:`text <target>``` shows ``text``;
* ``.. code-block:: LANG`` (or ``.. code::``) and the indented lines after it become a fenced block.

Inline code rather than cross-references: a reference to an object the site does not document would be a
warning, and the site is built with ``--strict``. Loaded by ``mkdocs.yml`` (mkdocstrings' ``extensions``).
"""

from __future__ import annotations

import re
from typing import Any

import griffe

_ROLE = re.compile(r":(?:py:)?(?:class|func|meth|mod|data|attr|exc|obj|const|ref|term):`([^`]+)`")
_DIRECTIVE = re.compile(r"^(?P<indent>[ \t]*)\.\. (?:code-block|code|sourcecode)::[ \t]*(?P<lang>\S*)[ \t]*$")


def _role(match: re.Match[str]) -> str:
    text = match.group(1).strip()
    labelled = re.fullmatch(r"(.+?)\s*<([^>]+)>", text)
    if labelled:
        return f"`{labelled.group(1)}`"
    if text.startswith("~"):
        text = text[1:].rsplit(".", 1)[-1]
    return f"`{text.lstrip('!')}`"


def _code_blocks(text: str) -> str:
    lines = text.split("\n")
    out: list[str] = []
    i = 0
    while i < len(lines):
        head = _DIRECTIVE.match(lines[i])
        if head is None:
            out.append(lines[i])
            i += 1
            continue
        indent, lang = head.group("indent"), head.group("lang")
        i += 1
        body: list[str] = []
        while i < len(lines) and (not lines[i].strip() or len(lines[i]) - len(lines[i].lstrip()) > len(indent)):
            body.append(lines[i])
            i += 1
        while body and not body[-1].strip():
            body.pop()
        while body and not body[0].strip():
            body.pop(0)
        depth = min((len(b) - len(b.lstrip()) for b in body if b.strip()), default=0)
        out += [f"{indent}```{lang}", *(indent + b[depth:] for b in body), f"{indent}```", ""]
    return "\n".join(out)


def sphinx_to_markdown(text: str) -> str:
    """``text`` (a docstring) with Sphinx roles as inline code and code-block directives as fenced blocks."""
    return _ROLE.sub(_role, _code_blocks(text))


class SphinxMarkup(griffe.Extension):
    """Rewrite every loaded object's docstring with :func:`sphinx_to_markdown`."""

    def on_instance(self, *, obj: griffe.Object, **kwargs: Any) -> None:
        if obj.docstring is not None:
            obj.docstring.value = sphinx_to_markdown(obj.docstring.value)
