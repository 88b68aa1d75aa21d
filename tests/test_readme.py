"""The README's code blocks run as written.

Rules (what each fenced block of README.md gets; a marker is an HTML comment, invisible when the
README is rendered, on the line right before the opening fence):

* ```` ```python ````: executed, in README order, in one namespace, in a scratch directory.
* ```` ```bash ````: every command runs in a shell in the same scratch directory and must exit 0,
  unless the block is marked ``<!-- readme-test: parse-only -->`` (installs, training, long
  episodes, videos): then each command is only *parsed*: ``swarm-env ...`` and ``python -m MOD ...``
  by their own argparse parsers (``build_parser()``), ``python FILE`` must name an existing file,
  ``pip install`` may name only extras that ``pyproject.toml`` defines.
* ``<!-- readme-test: file NAME -->``: the block is written to ``NAME`` in the scratch directory
  before anything runs (so that a command can use the README's example scenario file).
* ```` ```toml ```` and ```` ```yaml ```` blocks must parse; fences without a language are sample
  output and are not checked.
"""

from __future__ import annotations

import importlib
import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

if sys.version_info >= (3, 11):
    import tomllib
else:  # Python 3.10: the same parser from PyPI (the `dev` extra installs it there)
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
#: ``<!-- readme-test: parse-only (why) -->`` or ``<!-- readme-test: file NAME -->``; anything else is refused.
MARKER = re.compile(r"<!--\s*readme-test:\s*(?P<what>[\w-]+)\s*(?P<rest>.*?)\s*-->")


class Block:
    """One fenced code block of a Markdown file."""

    def __init__(self, lang: str, text: str, line: int, marker: tuple[str, str | None] | None) -> None:
        self.lang, self.text, self.line, self.marker = lang, text, line, marker

    def __repr__(self) -> str:
        return f"README.md:{self.line} ```{self.lang}"


def blocks(path: Path = README) -> list[Block]:
    """The fenced blocks of ``path`` with their language, first line number and marker (if any)."""
    out: list[Block] = []
    lines = path.read_text().splitlines()
    i = 0
    while i < len(lines):
        m = re.match(r"^```(\w*)\s*$", lines[i])
        if not m:
            i += 1
            continue
        j = i + 1
        while not lines[j].startswith("```"):
            j += 1
        prev = lines[i - 1] if i else ""
        mk = MARKER.search(prev)
        marker = None
        if mk:
            marker = (mk.group("what"), (mk.group("rest").split() or [None])[0] if mk.group("what") == "file" else None)
        out.append(Block(m.group(1), "\n".join(lines[i + 1 : j]) + "\n", i + 1, marker))
        i = j + 1
    return out


def commands(text: str) -> list[list[str]]:
    """The commands of a bash block: continuation lines joined, comments dropped, ``&&`` chains split,
    leading ``VAR=value`` assignments dropped; each command as its shell words."""
    joined = re.sub(r"\\\n", " ", text)
    out: list[list[str]] = []
    for line in joined.splitlines():
        words = shlex.split(line, comments=True)
        cmd: list[str] = []
        for w in [*words, "&&"]:
            if w == "&&":
                while cmd and re.match(r"^[A-Za-z_]\w*=", cmd[0]):
                    cmd.pop(0)
                if cmd:
                    out.append(cmd)
                cmd = []
            else:
                cmd.append(w)
    return out


def parse_command(cmd: list[str]) -> None:
    """Check one command without running it (the rules in the module docstring); ``AssertionError`` if it
    would fail to start."""
    if cmd[0] == "swarm-env":
        from swarm_env.harness.cli import MODULE_COMMANDS, build_parser

        for words, (module, _) in MODULE_COMMANDS.items():  # `swarm-env train mappo ...`: that module's parser
            if tuple(cmd[1 : 1 + len(words)]) == words:
                mod = importlib.import_module(module)
                assert hasattr(mod, "build_parser"), f"{shlex.join(cmd)}: {module} has no build_parser to check it"
                _parse(mod.build_parser(), cmd[1 + len(words):], cmd)
                return
        _parse(build_parser(), cmd[1:], cmd)
    elif cmd[0] in ("python", "python3") and cmd[1] == "-m" and cmd[2] != "pytest":
        module = importlib.import_module(cmd[2])
        if hasattr(module, "build_parser"):
            _parse(module.build_parser(), cmd[3:], cmd)
    elif cmd[0] in ("python", "python3") and cmd[1] != "-m":
        assert (ROOT / cmd[1]).is_file(), f"{shlex.join(cmd)}: no file {cmd[1]}"
    elif cmd[:2] == ["pip", "install"]:
        extras = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"])
        for word in cmd[2:]:
            m = re.fullmatch(r"\.\[([\w,-]+)\]|swarm-env\[([\w,-]+)\]", word)
            if m:
                named = set((m.group(1) or m.group(2)).split(","))
                assert named <= extras, f"{shlex.join(cmd)}: no extra {sorted(named - extras)} in pyproject.toml"
    elif cmd[0] in ("ruff", "mypy", "tensorboard"):  # the dev extra's linter and type checker; the rl extra's viewer
        assert shutil.which(cmd[0]), f"{shlex.join(cmd)}: {cmd[0]} is not installed (the dev or rl extra has it)"
    elif cmd[:3] != ["python", "-m", "pytest"]:
        raise AssertionError(f"no rule to check the README command {shlex.join(cmd)!r}")


def _parse(parser, args: list[str], cmd: list[str]) -> None:
    try:
        parser.parse_args(args)
    except SystemExit as exc:
        raise AssertionError(f"README command does not parse: {shlex.join(cmd)} (exit {exc.code})") from None


@pytest.fixture(scope="module")
def scratch(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The directory the README's blocks run in, holding its ``file`` blocks."""
    d = tmp_path_factory.mktemp("readme")
    for b in blocks():
        if b.marker and b.marker[0] == "file":
            (d / b.marker[1]).write_text(b.text)
    return d


def test_markers_are_known_and_blocks_found() -> None:
    found = blocks()
    assert sum(b.lang == "python" for b in found) >= 1 and sum(b.lang == "bash" for b in found) >= 3
    assert sum(b.marker is not None for b in found) == len(MARKER.findall(README.read_text())), \
        "a readme-test marker must sit on the line right before a fence"
    for b in found:
        if b.marker:
            assert b.marker[0] in ("parse-only", "file"), f"{b}: unknown marker {b.marker}"
            assert b.marker[0] != "file" or b.marker[1], f"{b}: 'file' needs a NAME"


def test_first_command_shows_an_expert_with_a_video() -> None:
    """The first command a reader meets runs an expert (not the no-avoidance baseline) and writes a video."""
    first = next(c for b in blocks() if b.lang == "bash" for c in commands(b.text) if c[0] == "swarm-env")
    args = __import__("swarm_env.harness.cli", fromlist=["build_parser"]).build_parser().parse_args(first[1:])
    assert args.command == "run" and args.policy.split(":")[0] in ("vo", "cbs_rrt") and args.video, first


@pytest.mark.parametrize("block", [b for b in blocks() if b.lang in ("toml", "yaml")], ids=repr)
def test_config_blocks_parse(block: Block) -> None:
    (tomllib.loads if block.lang == "toml" else yaml.safe_load)(block.text)


def test_python_blocks_run(scratch: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(scratch)
    namespace: dict = {"__name__": "__readme__"}
    for b in blocks():
        if b.lang == "python":
            exec(compile(b.text, repr(b), "exec"), namespace)  # noqa: S102 - the README's own code


@pytest.mark.parametrize("block", [b for b in blocks() if b.lang == "bash"], ids=repr)
def test_bash_blocks(block: Block, scratch: Path) -> None:
    cmds = commands(block.text)
    assert cmds, f"{block}: no command"
    if block.marker and block.marker[0] == "parse-only":
        for cmd in cmds:
            parse_command(cmd)
        return
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}",
           "SDL_VIDEODRIVER": "dummy", "OPENBLAS_NUM_THREADS": "1"}
    for cmd in cmds:
        out = subprocess.run(shlex.join(cmd), shell=True, cwd=scratch, env=env, capture_output=True, text=True,
                             timeout=120)
        assert out.returncode == 0, f"{block}: {shlex.join(cmd)} exited {out.returncode}:\n{out.stdout}\n{out.stderr}"
