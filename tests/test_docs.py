"""Docs that run: the code blocks of README.md and docs/*.md are held against the code.

What each block gets is chosen by a marker, an HTML comment on the line before the block
(docs/writing_docs.md):

- A Python block runs, in this process, in a fresh folder holding ``plant.fmu`` (the cart-pole FMU),
  ``experiment.yaml`` (its starting experiment, as ``fmu-bridge init`` writes it) and ``examples/``.
  ``<!-- run: integration -->`` says the block starts processes: it runs in the integration tier.
  ``<!-- no-run: REASON -->`` says why it cannot run here: it is compiled and its imports run.
- Every ``fmu-bridge`` command a shell block (bash, sh) names must exist. ``<!-- run -->`` runs the
  block with ``bash -e`` in such a folder (without ``experiment.yaml``: the commands start from the
  FMU), within a time bound, in the integration tier.
- A YAML block must parse.
"""

from __future__ import annotations

import ast
import os
import re
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from types import CodeType

import pytest
import typer
import yaml
from markdown_it import MarkdownIt

from bridge.cli.main import _load_plugins, app
from bridge.experiment.init import starting_config
from bridge.models import example_fmu

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
PYTHON = {"python", "py"}
SHELL = {"bash", "sh", "shell"}
MARKER = re.compile(r"<!--\s*(?P<kind>run|no-run)(?::\s*(?P<arg>.*?))?\s*-->", re.DOTALL)
SHELL_TIMEOUT_S = 600


@dataclass(frozen=True)
class Block:
    """One fenced code block: where it is, its language, its text and its marker."""

    path: Path
    line: int  # 1-based line of the block's first code line
    lang: str
    code: str
    marker: str | None  # "run", "no-run" or None
    arg: str  # the marker's argument: the reason of a no-run, "integration" for a run

    @property
    def where(self) -> str:
        shown = self.path.relative_to(ROOT) if self.path.is_relative_to(ROOT) else self.path
        return f"{shown}:{self.line}"


def blocks_of(path: Path, text: str | None = None) -> list[Block]:
    """The fenced code blocks of a Markdown file, each with the marker right before it (if any)."""
    tokens = MarkdownIt("commonmark").parse(path.read_text() if text is None else text)
    found = []
    for before, token in zip([None, *tokens], tokens):
        if token.type != "fence" or token.map is None:
            continue
        marker, arg = None, ""
        if before is not None and before.type == "html_block":
            match = MARKER.fullmatch(before.content.strip())
            if match:
                marker, arg = match["kind"], (match["arg"] or "").strip()
        lang = token.info.split()[0].lower() if token.info.strip() else ""
        found.append(Block(path, token.map[0] + 2, lang, token.content, marker, arg))
    return found


def marker_problems(block: Block) -> str | None:
    """What is wrong with a block's marker, or None."""
    if block.marker is None:
        return None
    if block.lang not in PYTHON | SHELL:
        return f"a {block.marker!r} marker on a {block.lang or 'plain'} block: only Python and shell run"
    if block.marker == "no-run" and not block.arg:
        return "<!-- no-run --> without a reason: write <!-- no-run: what it needs -->"
    if block.marker == "run" and block.arg not in ("", "integration"):
        return f"<!-- run: {block.arg} -->: expected <!-- run --> or <!-- run: integration -->"
    return None


ALL = [block for path in DOCS for block in blocks_of(path)]
PY_FAST = [b for b in ALL if b.lang in PYTHON and not (b.marker == "run" and b.arg == "integration")]
PY_PROCESSES = [b for b in ALL if b.lang in PYTHON and b.marker == "run" and b.arg == "integration"]
SH_RUN = [b for b in ALL if b.lang in SHELL and b.marker == "run"]


def _compiled(block: Block, tree: ast.Module) -> CodeType:
    # Line numbers in tracebacks are the Markdown file's, so an error points into the doc.
    ast.increment_lineno(tree, block.line - 1)
    return compile(tree, block.where, "exec")


def run_imports(block: Block) -> None:
    """Compile a block and run its import statements (all of them, wherever they stand)."""
    tree = ast.parse(block.code, block.where)
    imports: list[ast.stmt] = [n for n in ast.walk(tree) if isinstance(n, (ast.Import, ast.ImportFrom))]
    exec(_compiled(block, ast.Module(body=imports, type_ignores=[])), {"__name__": "doc_block"})


def run_python(block: Block) -> None:
    """Run a whole block as a script would (in the current folder)."""
    tree = ast.parse(block.code, block.where)
    exec(_compiled(block, tree), {"__name__": "__main__"})


def _skip_when_an_optional_package_is_missing(block: Block, exc: ModuleNotFoundError) -> None:
    top = (exc.name or "").split(".")[0]
    if top in ("bridge", "agents", ""):
        raise AssertionError(f"{block.where}: {exc}: the block imports a module that does not exist") from exc
    pytest.skip(f"{block.where} needs {top}, which is not installed here")


@pytest.fixture(scope="session")
def cartpole_fmu() -> Path:
    return Path(example_fmu("cartpole", "2.0", "cs"))


def _folder(tmp_path: Path, fmu: Path, *, experiment: bool) -> Path:
    shutil.copy(fmu, tmp_path / "plant.fmu")
    (tmp_path / "examples").symlink_to(ROOT / "examples", target_is_directory=True)
    if experiment:
        text = starting_config(tmp_path / "plant.fmu", relative_to=tmp_path)
        (tmp_path / "experiment.yaml").write_text(text)
    return tmp_path


def _run_python_block(block: Block, tmp_path: Path, fmu: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    try:
        if block.marker == "no-run":
            run_imports(block)
            return
        monkeypatch.chdir(_folder(tmp_path, fmu, experiment=True))
        run_python(block)
    except ModuleNotFoundError as exc:
        _skip_when_an_optional_package_is_missing(block, exc)


def test_every_marker_is_understood() -> None:
    problems = [f"{b.where}: {p}" for b in ALL if (p := marker_problems(b))]
    unmarked = [
        f"{path.relative_to(ROOT)}: {comment.strip()!r} is not a marker"
        for path in DOCS
        for comment in re.findall(r"<!--\s*(?:run|no-run)\b.*?-->", path.read_text(), re.DOTALL)
        if not MARKER.fullmatch(comment.strip())
    ]
    assert problems + unmarked == []
    assert PY_FAST and SH_RUN, "the docs have runnable Python and shell blocks"


@pytest.mark.parametrize("block", PY_FAST, ids=lambda b: b.where)
def test_python_block(
    block: Block, tmp_path: Path, cartpole_fmu: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    _run_python_block(block, tmp_path, cartpole_fmu, monkeypatch)


@pytest.mark.integration
@pytest.mark.parametrize("block", PY_PROCESSES, ids=lambda b: b.where)
def test_python_block_that_starts_processes(
    block: Block, tmp_path: Path, cartpole_fmu: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    _run_python_block(block, tmp_path, cartpole_fmu, monkeypatch)


def _commands() -> dict[str, set[str]]:
    _load_plugins()  # agents' train, evaluate, agent, ... as the console entry point adds them
    group = typer.main.get_command(app)
    commands: dict[str, set[str]] = {}
    for name, command in group.commands.items():  # type: ignore[attr-defined]
        commands[name] = set(getattr(command, "commands", {}))
    return commands


def named_commands(code: str) -> list[list[str]]:
    """The ``fmu-bridge`` invocations of a shell block: the words after the program name."""
    text = code.replace("\\\n", " ")
    text = re.sub(r"(^|\s)#.*", "", text)  # comments
    pattern = r"(?:^|[;&|(]|\s)fmu-bridge((?:\s+[a-z][\w-]*){1,2})"
    return [m.group(1).split() for m in re.finditer(pattern, text)]


def test_every_command_a_shell_block_names_exists() -> None:
    commands = _commands()
    wrong = []
    for block in (b for b in ALL if b.lang in SHELL):
        for words in named_commands(block.code):
            sub = commands.get(words[0])
            if sub is None:
                wrong.append(
                    f"{block.where}: fmu-bridge {words[0]}: no such command; known: {sorted(commands)}"
                )
            elif sub and (len(words) < 2 or words[1] not in sub):
                wrong.append(f"{block.where}: fmu-bridge {' '.join(words)}: {words[0]} takes {sorted(sub)}")
    assert wrong == []


@pytest.mark.integration
@pytest.mark.parametrize("block", SH_RUN, ids=lambda b: b.where)
def test_shell_block(block: Block, tmp_path: Path, cartpole_fmu: Path) -> None:
    folder = _folder(tmp_path, cartpole_fmu, experiment=False)
    bindir = str(Path(sys.executable).parent)  # this venv's fmu-bridge
    env = {**os.environ, "PATH": bindir + os.pathsep + os.environ.get("PATH", ""), "PYTHONPATH": str(ROOT)}
    script = "set -euo pipefail\n" + block.code
    try:
        result = subprocess.run(
            ["bash", "-c", script],
            check=False,
            cwd=folder,
            env=env,
            capture_output=True,
            text=True,
            timeout=SHELL_TIMEOUT_S,
        )
    except subprocess.TimeoutExpired as exc:
        raise AssertionError(f"{block.where}: still running after {SHELL_TIMEOUT_S} s") from exc
    assert result.returncode == 0, f"{block.where} failed ({result.returncode}):\n{result.stderr[-3000:]}"


def test_every_yaml_block_parses() -> None:
    wrong = []
    for block in (b for b in ALL if b.lang in ("yaml", "yml")):
        try:
            yaml.safe_load(block.code)
        except yaml.YAMLError as exc:
            wrong.append(f"{block.where}: not YAML: {exc}")
    assert wrong == []


# The checker itself: a block that imports a module gone since the package move must fail.


def test_a_block_importing_a_module_that_is_gone_fails(tmp_path: Path) -> None:
    page = tmp_path / "page.md"
    page.write_text(
        "<!-- no-run: needs a Zenoh router -->\n```python\nfrom bridge.transport import ZenohOptions\n"
        "session = open_session(ZenohOptions())\n```\n"
    )
    (block,) = blocks_of(page)
    assert (block.marker, block.arg, block.line) == ("no-run", "needs a Zenoh router", 3)
    with pytest.raises(ModuleNotFoundError, match=r"bridge\.transport"):
        run_imports(block)
    moved = Block(page, 3, "python", "from bridge.net.transport import ZenohOptions\n", "no-run", "router")
    run_imports(moved)  # where it lives now


def test_markers_need_a_reason_and_a_runnable_language(tmp_path: Path) -> None:
    page = tmp_path / "page.md"
    page.write_text("<!-- no-run -->\n```python\nx = 1\n```\n\n<!-- run -->\n```yaml\na: 1\n```\n")
    problems = [marker_problems(b) for b in blocks_of(page)]
    assert problems[0] is not None and "without a reason" in problems[0]
    assert problems[1] is not None and "yaml" in problems[1]


def test_named_commands_follow_continuations_and_skip_comments() -> None:
    code = "fmu-bridge evaluate runs/a \\\n  --config x.yaml  # fmu-bridge nothing\n"
    code += "fmu-bridge system check s.ssp\n"
    assert named_commands(code) == [["evaluate", "runs"], ["system", "check"]]


# Package docstrings name their modules: each must exist.


def test_package_docstrings_name_modules_that_exist() -> None:
    wrong = []
    for init in sorted([*(ROOT / "bridge").rglob("__init__.py"), *(ROOT / "agents").rglob("__init__.py")]):
        doc = ast.get_docstring(ast.parse(init.read_text())) or ""
        for literal, module in re.findall(r"``([\w.]+)``|:mod:`~?([\w.]+)`", doc):
            name = literal or module
            if name.endswith((".c", ".py")):  # in the package (or, for the example models, in models/)
                if not any(init.parent.rglob(name)) and not any((ROOT / "models").rglob(name)):
                    wrong.append(f"{init.relative_to(ROOT)}: no {name} in {init.parent.relative_to(ROOT)}")
            elif name.startswith(("bridge.", "agents.")) and not _resolves(name):
                wrong.append(f"{init.relative_to(ROOT)}: {name} does not exist")
    assert wrong == []


def _resolves(dotted: str) -> bool:
    parts = dotted.split(".")
    for cut in range(len(parts), 0, -1):
        base = ROOT.joinpath(*parts[:cut])
        if base.is_dir() or base.with_suffix(".py").is_file():
            rest = parts[cut:]
            if not rest:
                return True
            module = __import__(".".join(parts[:cut]), fromlist=["_"])
            obj: object = module
            for attr in rest:
                if not hasattr(obj, attr):
                    return False
                obj = getattr(obj, attr)
            return True
    return False


# The README is the front door: short, the two set-up commands first, every link leading somewhere.


def test_the_readme_is_a_short_front_door_whose_links_lead_somewhere() -> None:
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 300, "README.md: at most 300 lines; move the details to a page in docs/"
    first_two = [b.code for b in blocks_of(ROOT / "README.md")][:2]
    assert all(code.startswith("python3 -m venv .venv && ") for code in first_two), first_two
    targets = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text)
    broken = [t for t in targets if "://" not in t and not (ROOT / t).exists()]
    assert targets and broken == [], f"README.md links to files that do not exist: {broken}"
