"""Every example of the README and the documentation site runs, so none can rot (issue 21, item 7).

- Each ```python block of README.md and docs/**/*.md runs, the blocks of one document in order in one
  namespace (a later block may use an earlier one's `crane`), in a temporary folder as the working
  directory. A block that deliberately does not run is preceded by `<!-- not-run: why -->`; such blocks
  are counted here (NOT_RUN), so a new one is a decision, not an accident.
- Each command line of a ```sh block (and each inline code span) that starts with `acroboter `,
  `python -m acroboter` or `make ` is checked: an acroboter command is parsed by the real argparse
  parser of its subcommand (through the console's dispatch, stopped right after the subcommand has
  parsed, before any work), so a renamed or removed option or subcommand fails here; a make target
  must be a rule of the Makefile. Placeholders: an inline span with `<...>`, `[...]`, `*` or `...` is a
  synopsis and not parsed; a trailing `...` in a block means "more options of the same kind" and is
  dropped. A command line in a fenced block without a language fails: label it `sh` (checked) or
  `text` (a synopsis).
- The examples in the docstrings the API reference shows (indented blocks that use acroboter) run too.
- README.md stays a front door (at most 250 lines), and the site builds with `mkdocs build --strict`
  (no broken link, no missing API reference, no docstring the API reference cannot read).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import re
import shlex
import subprocess
import sys
from dataclasses import dataclass
from importlib import import_module
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
DOCUMENTS = [REPO / "README.md", *sorted((REPO / "docs").rglob("*.md"))]
README_MAX_LINES = 250
# document (relative to the repository) -> how many of its python blocks are marked not-run
NOT_RUN: dict[str, int] = {}
SHELL_LANGUAGES = {"sh", "bash", "shell", "console"}
COMMAND = re.compile(r"^(acroboter(\s|$)|python -m acroboter\b|make(\s|$))")


@dataclass
class Block:
    document: Path
    line: int  # 1-based line of the first line of code
    language: str
    code: str
    not_run: str | None  # the reason, when marked <!-- not-run: why -->

    @property
    def where(self) -> str:
        return f"{self.document.relative_to(REPO)}:{self.line}"


def fenced_blocks(document: Path) -> list[Block]:
    """The fenced code blocks of a markdown file (also those indented inside list items)."""
    lines = document.read_text().splitlines()
    blocks, i = [], 0
    while i < len(lines):
        opening = re.match(r"^(\s*)```\s*([\w+-]*)\s*$", lines[i])
        if not opening:
            i += 1
            continue
        indent, language = opening.group(1), opening.group(2).lower()
        previous = next((lines[j].strip() for j in range(i - 1, -1, -1) if lines[j].strip()), "")
        marker = re.fullmatch(r"<!--\s*not-run:\s*(.+?)\s*-->", previous)
        end = i + 1
        while end < len(lines) and not re.match(r"^\s*```\s*$", lines[end]):
            end += 1
        assert end < len(lines), f"{document.relative_to(REPO)}:{i + 1}: a fenced block that never closes"
        code = "\n".join(line[len(indent):] if line.startswith(indent) else line for line in lines[i + 1:end])
        blocks.append(Block(document, i + 2, language, code + "\n", marker.group(1) if marker else None))
        i = end + 1
    return blocks


def inline_commands(document: Path) -> list[tuple[str, str]]:
    """(where, command) of the inline code spans outside fenced blocks that are a command line (a span
    may wrap onto the next line, as a paragraph's text does)."""
    lines = document.read_text().splitlines()
    fenced = False
    for i, line in enumerate(lines):  # blank out the fenced blocks, keeping the line numbers
        if re.match(r"^\s*```", line):
            fenced = not fenced
            lines[i] = ""
        elif fenced:
            lines[i] = ""
    text = "\n".join(lines)
    found = []
    for match in re.finditer(r"(?<!`)`([^`\n]+(?:\n[^`\n]+)?)`(?!`)", text):
        span = " ".join(match.group(1).split())
        if COMMAND.match(span) and not re.search(r"<[^>]*>|\[|\.\.\.|…|\*", span):
            found.append((f"{document.relative_to(REPO)}:{text.count(chr(10), 0, match.start()) + 1}", span))
    return found


def shell_commands(block: Block) -> list[tuple[str, str]]:
    """(where, command) of a shell block's lines that run acroboter or make (continuations joined)."""
    commands, pending, start = [], "", 0
    for offset, line in enumerate(block.code.splitlines()):
        if not pending:
            start = offset
        pending += line.rstrip()
        if pending.endswith("\\"):
            pending = pending[:-1] + " "
            continue
        text = re.sub(r"^(\$ )?([A-Z_][A-Z0-9_]*=\S* )*", "", pending.strip())  # a prompt, VAR=value prefixes
        pending = ""
        if COMMAND.match(text):
            commands.append((f"{block.document.relative_to(REPO)}:{block.line + start}", text))
    return commands


ALL_BLOCKS = [block for document in DOCUMENTS for block in fenced_blocks(document)]
PYTHON_DOCUMENTS = sorted({b.document for b in ALL_BLOCKS if b.language == "python"})
SHELL_COMMANDS = [c for b in ALL_BLOCKS if b.language in SHELL_LANGUAGES for c in shell_commands(b)]
INLINE_COMMANDS = [c for document in DOCUMENTS for c in inline_commands(document)]


# --- the python blocks --------------------------------------------------------------------------------------


@pytest.mark.parametrize("document", PYTHON_DOCUMENTS, ids=lambda d: str(d.relative_to(REPO)))
def test_the_python_examples_run(document, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("MPLBACKEND", "Agg")
    namespace: dict = {"__name__": "__docs_example__"}
    for block in (b for b in ALL_BLOCKS if b.document == document and b.language == "python"):
        if block.not_run is not None:
            continue
        # compiled at the block's own line, so a traceback points into the markdown file
        code = compile("\n" * (block.line - 1) + block.code, str(document), "exec")
        with contextlib.redirect_stdout(io.StringIO()):
            exec(code, namespace)  # noqa: S102 - the documentation's own examples


def test_not_run_blocks_are_rare_and_counted():
    marked: dict[str, int] = {}
    for block in ALL_BLOCKS:
        if block.not_run is not None:
            assert block.language == "python", f"{block.where}: not-run marks a python block"
            key = str(block.document.relative_to(REPO))
            marked[key] = marked.get(key, 0) + 1
    assert marked == NOT_RUN, "a python block marked <!-- not-run: why --> is added or removed: update NOT_RUN"


# --- the command lines --------------------------------------------------------------------------------------


class _Parsed(BaseException):
    """Raised right after the subcommand's parser accepted the arguments: nothing runs."""


def _makefile_targets() -> set[str]:
    text = (REPO / "Makefile").read_text()
    return set(re.findall(r"^([A-Za-z][\w.-]*)\s*:(?!=)", text, flags=re.M))


def _console_parser(parser: argparse.ArgumentParser) -> bool:
    from acroboter.cli import console

    return parser.description == console.__doc__


def _words(command: str) -> list[str]:
    words = shlex.split(command, comments=True)
    return words[:-1] if words and words[-1] == "..." else words


def _entry(words: list[str]):
    """(the main function, its argv) of an acroboter command line."""
    if words[0] == "acroboter":
        return import_module("acroboter.cli.console").main, words[1:]
    assert words[:2] == ["python", "-m"], words  # python -m acroboter[.module] ...
    module = words[2]
    return import_module("acroboter.cli.console" if module == "acroboter" else module).main, words[3:]


def _call_until_parsed(main, argv: list[str], parse: bool) -> tuple[argparse.ArgumentParser | None, str | None]:
    """Call a command's main until its own (not the console's) parser is reached: with parse, that parser
    parses argv first. Returns (that parser, None) or (None, why argparse refused)."""
    original = argparse.ArgumentParser.parse_args
    reached: list[argparse.ArgumentParser] = []

    def parse_then_stop(self, args=None, namespace=None):
        if _console_parser(self):
            return original(self, args, namespace)
        if parse:
            self.allow_abbrev = False  # a documented option is written out: `--plant-param` is not `--plant-parameter`
            original(self, args, namespace)
        reached.append(self)
        raise _Parsed

    original_intermixed = argparse.ArgumentParser.parse_intermixed_args

    def intermixed_then_stop(self, args=None, namespace=None):  # `generate --out DIR SPEC` (acroboter.cli.generate)
        if parse:
            self.allow_abbrev = False
            original_intermixed(self, args, namespace)
        reached.append(self)
        raise _Parsed

    stderr = io.StringIO()
    argparse.ArgumentParser.parse_args = parse_then_stop
    argparse.ArgumentParser.parse_intermixed_args = intermixed_then_stop
    try:
        with contextlib.redirect_stderr(stderr), contextlib.redirect_stdout(io.StringIO()):
            main(argv)
    except _Parsed:
        return reached[0], None
    except SystemExit as exit_:  # argparse: --help / --version exit 0, a bad option 2
        if exit_.code in (0, None):
            return None, None
        return None, f"argparse refused it: {stderr.getvalue().strip()}"
    finally:
        argparse.ArgumentParser.parse_args = original
        argparse.ArgumentParser.parse_intermixed_args = original_intermixed
    return None, "the command returned without parsing its options (nothing checked)"


def _make_problem(words: list[str]) -> str | None:
    targets = [w for w in words[1:] if "=" not in w and not w.startswith("-")]
    missing = sorted(set(targets) - _makefile_targets())
    return f"no Makefile target {missing}" if missing else None


def check_command(command: str) -> str | None:
    """A command line of a shell block: None if the subcommand's parser accepts it, else why not."""
    words = _words(command)
    if words[0] == "make":
        return _make_problem(words)
    main, argv = _entry(words)
    _, problem = _call_until_parsed(main, argv, parse=True)
    return problem


CONSOLE_OPTIONS = {"-q", "--quiet", "-v", "--verbose", "--version", "-h", "--help"}


def check_mention(command: str) -> str | None:
    """A command named in prose (an inline code span, such as `acroboter run --plant-param`): its
    subcommand exists and every option it names is one of that subcommand's (values are not judged)."""
    words = _words(command)
    if words[0] == "make":
        return _make_problem(words)
    main, argv = _entry(words)
    if words[0] == "acroboter" or words[2] == "acroboter":  # through the console: its options, then COMMAND
        from acroboter.cli.console import COMMANDS

        while argv and argv[0] in CONSOLE_OPTIONS:
            argv = argv[1:]
        if not argv:
            return None
        if argv[0] not in COMMANDS:
            return f"no subcommand '{argv[0]}' (the commands: {', '.join(COMMANDS)})"
        argv = [argv[0], *argv[1:]]
    options = [w.split("=", 1)[0] for w in argv if w.startswith("-") and w not in CONSOLE_OPTIONS]
    parser, problem = _call_until_parsed(main, argv[:1] + ["--help"] if argv else ["--help"], parse=False)
    if problem:
        return problem
    if parser is None:  # a command without options of its own
        return f"{options} named, but the command has no options" if options else None
    unknown = [o for o in options if o not in parser._option_string_actions]
    return f"not an option of `{parser.prog}`: {unknown}" if unknown else None


@pytest.mark.parametrize("where,command", SHELL_COMMANDS, ids=[w for w, _ in SHELL_COMMANDS])
def test_the_command_lines_parse(where, command, monkeypatch):
    monkeypatch.chdir(REPO)  # `--spec model_spec/acroboter.toml` as in a checkout
    problem = check_command(command)
    assert problem is None, f"{where}: `{command}`: {problem}"


@pytest.mark.parametrize("where,command", INLINE_COMMANDS, ids=[w for w, _ in INLINE_COMMANDS])
def test_the_commands_named_in_prose_exist(where, command, monkeypatch):
    monkeypatch.chdir(REPO)
    problem = check_mention(command)
    assert problem is None, f"{where}: `{command}`: {problem}"


def test_command_lines_in_unlabelled_blocks_are_refused():
    for block in ALL_BLOCKS:
        if block.language == "":
            for line in block.code.splitlines():
                assert not COMMAND.match(line.strip()), (f"{block.where}: a command line in a block without a "
                                                         "language: `sh` checks it, `text` is a synopsis")


def test_the_examples_are_found():
    """The extraction itself: the README's set-up and library example, and many commands are seen."""
    readme = [b for b in ALL_BLOCKS if b.document.name == "README.md"]
    assert any(b.language == "python" for b in readme)
    assert {"make run", "make test"} <= {c.split("#")[0].strip() for _, c in SHELL_COMMANDS if _.startswith("README")}
    assert len(SHELL_COMMANDS) >= 20 and len(INLINE_COMMANDS) >= 20
    assert check_command("acroboter run --no-such-option 1") is not None  # the check can fail
    assert check_command("acroboter no-such-command") is not None
    assert check_command("make no-such-target") is not None
    assert check_mention("acroboter run --no-such-option") is not None
    assert check_mention("acroboter no-such-command --spec x") is not None
    assert check_mention("acroboter run --plant-param") is None


# --- the README and the site --------------------------------------------------------------------------------


def test_the_readme_is_a_front_door():
    lines = (REPO / "README.md").read_text().splitlines()
    assert len(lines) <= README_MAX_LINES, f"README.md: {len(lines)} lines (at most {README_MAX_LINES})"


def test_the_site_builds_strict(tmp_path):
    pytest.importorskip("mkdocs", reason="the docs extra: pip install -e '.[docs]' (make setup installs it)")
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    proc = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
                          cwd=REPO, capture_output=True, text=True, env=env, timeout=600)
    assert proc.returncode == 0, proc.stderr[-4000:]
    assert (tmp_path / "site" / "api" / "crane" / "index.html").is_file()


def test_the_run_synopsis_names_every_option():
    """docs/run.md's synopsis of `acroboter run` is the parser's option list, no more, no less."""
    from acroboter.cli.console import main

    synopsis = next(b.code for b in ALL_BLOCKS
                    if b.document.name == "run.md" and b.language == "text" and b.code.startswith("acroboter run ["))
    named = set(re.findall(r"(?<![\w-])(--?[a-z][\w-]*)", synopsis))
    parser, problem = _call_until_parsed(main, ["run", "--help"], parse=False)
    assert parser is not None, problem
    actions = [a for a in parser._actions if a.option_strings and "--help" not in a.option_strings]
    missing = [a.option_strings[-1] for a in actions if not named & set(a.option_strings)]
    unknown = sorted(named - {o for a in actions for o in a.option_strings})
    assert not missing and not unknown, f"docs/run.md synopsis: missing {missing}, not options {unknown}"


# --- the docstrings' examples the API reference shows ---------------------------------------------------


def _api_objects() -> list[str]:
    """The dotted names the API reference renders (`::: acroboter.api.crane.Crane`), and the package."""
    names = {"acroboter"}
    for page in sorted((REPO / "docs" / "api").glob("*.md")):
        names |= set(re.findall(r"^::: ([\w.]+)", page.read_text(), flags=re.M))
    return sorted(names)


def _resolve(dotted: str):
    parts = dotted.split(".")
    for split in range(len(parts), 0, -1):
        try:
            obj = import_module(".".join(parts[:split]))
        except ImportError:
            continue
        for attribute in parts[split:]:
            obj = getattr(obj, attribute)
        return obj
    raise ImportError(dotted)


def docstring_examples(dotted: str) -> list[str]:
    """The indented blocks of a docstring that use acroboter (markdown shows them as code)."""
    import inspect

    doc = inspect.getdoc(_resolve(dotted)) or ""
    blocks = re.findall(r"(?:^|\n\n)((?: {4}.*\n?|\n)+)", doc + "\n")
    examples = [inspect.cleandoc("\n" + b) for b in blocks]
    return [e for e in examples if "acroboter." in e]


DOCSTRING_EXAMPLES = [(name, code) for name in _api_objects() for code in docstring_examples(name)]


@pytest.mark.parametrize("name,code", DOCSTRING_EXAMPLES, ids=[n for n, _ in DOCSTRING_EXAMPLES])
def test_the_docstring_examples_run(name, code, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("MPLBACKEND", "Agg")
    with contextlib.redirect_stdout(io.StringIO()):
        exec(compile(code, f"<docstring of {name}>", "exec"), {"__name__": "__docs_example__"})  # noqa: S102


def test_the_spec_reference_names_every_field():
    """docs/spec.md names (in code spans) every field of every table of the spec's schema."""
    import typing

    import pydantic

    from acroboter.model.spec import Spec

    text = re.sub(r"```.*?```", "", (REPO / "docs" / "spec.md").read_text(), flags=re.S)
    named = {word for span in re.findall(r"`([^`]+)`", text) for word in re.findall(r"\w+", span)}
    missing, seen = [], set()

    def models(annotation):
        if isinstance(annotation, type) and issubclass(annotation, pydantic.BaseModel):
            yield annotation
        for argument in typing.get_args(annotation):
            yield from models(argument)

    def walk(model, path):
        if model in seen:
            return
        seen.add(model)
        for name, field in model.model_fields.items():
            if name not in named:
                missing.append(f"{path}.{name}")
            for sub in models(field.annotation):
                walk(sub, f"{path}.{name}")

    walk(Spec, "spec")
    assert not missing, f"docs/spec.md does not name {missing}"
