"""Every command the documentation shows still parses, with values in their ranges.

The README, ``docs/`` and the result files show hundreds of ``mivecc ...`` and
``python benchmarks/...`` commands, most of them next to a number they produced. A renamed
option, a removed choice or a narrowed range would break them without any other test
noticing. This test reads every tracked Markdown file (fenced code blocks, with continued lines
joined, and inline code spans such as a result file's ``Command: `...` `` line) and hands each
command to its own parser (the ``mivecc`` CLI's or the script's ``main``), stopping right after
the options are parsed: nothing runs. Then it checks what the parsers leave to later code:
``mivecc train``'s pre-training checks (presets, ``--preset-set`` fields, densities, frames)
and every ``--set`` field against the config's ranges.

Not checked: that files the commands name exist (runs of earlier sessions live under ``runs/``,
outside the repository); the commands written as patterns (``$s``, ``<checkpoint>``,
``[--cloud ...]``), which are counted and skipped; a span that only names a script or a
subcommand (``python benchmarks/table_diff.py``); and commands for a GPU where torch sees none
(their device option is checked against the machine).
"""

from __future__ import annotations

import argparse
import contextlib
import inspect
import io
import re
import shlex
import sys
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from mivecc_env import cli_args
from mivecc_env.config import from_overrides
from tests.scripts import ParsedError, load_benchmark, stop_after_parsing
from tests.test_docs_references import ROOT, _tracked_text_files

#: A command line this test checks: optional ``VAR=value`` words, an optional ``/usr/bin/time``
#: with its flags, then the CLI or a benchmark script.
START = re.compile(
    r"^(?:[A-Z_]+=\S+\s+)*(?:/usr/bin/time\s+(?:-\S+\s+)*)?"
    r"(?:mivecc\s|python\s+benchmarks/\w+\.py)"
)
#: Words that make a command a pattern for the reader to fill in.
PATTERN_MARKS = ("$", "<", "[", "...", "{")
#: A Markdown inline code span.
INLINE_CODE = re.compile(r"`([^`\n]+)`")
#: The fewest commands the docs must yield (383 checkable ones of 489 in session 35): guards
#: against an extractor that silently finds nothing.
MIN_CHECKED = 350


@dataclass(frozen=True)
class DocCommand:
    """One command of a fenced code block: where it is and its words."""

    where: str
    words: tuple[str, ...]

    @property
    def is_pattern(self) -> bool:
        """Written for the reader to fill in (``$s``, ``<checkpoint>``, ...)."""
        return any(mark in word for word in self.words for mark in PATTERN_MARKS)

    @property
    def is_name(self) -> bool:
        """Only names a script or a ``mivecc`` subcommand (prose, not a command)."""
        return len(self.words) <= 2

    @property
    def needs_gpu(self) -> bool:
        """Names a CUDA device, which the parser checks against this machine."""
        import torch

        return any("cuda" in word for word in self.words) and not torch.cuda.is_available()

    @property
    def checkable(self) -> bool:
        return not (self.is_pattern or self.is_name or self.needs_gpu)


def _logical_lines(block: list[tuple[int, str]]) -> Iterator[tuple[int, str]]:
    """Lines of a code block with backslash continuations joined, trailing comments cut."""
    start, parts = 0, []
    for number, line in block:
        if not parts:
            start = number
        text = line.rstrip()
        parts.append(text.removesuffix("\\").strip())
        if not text.endswith("\\"):
            yield start, re.sub(r"\s+#.*$", "", " ".join(parts))
            parts = []
    if parts:
        yield start, " ".join(parts)


def timed_commands(words: Sequence[str]) -> list[tuple[str, ...]]:
    """The commands a ``python benchmarks/time_commands.py`` command times: A after ``--``
    and B of ``--vs`` (none for any other command)."""
    if len(words) < 2 or Path(words[1]).name != "time_commands.py":
        return []
    timed = []
    if "--" in words:
        timed.append(tuple(words[words.index("--") + 1:]))
    if "--vs" in words[:-1]:
        timed.append(tuple(shlex.split(words[words.index("--vs") + 1])))
    return timed


def doc_commands(path: Path) -> Iterator[DocCommand]:
    """The ``mivecc`` and ``python benchmarks/...`` commands in ``path``: in its fenced blocks
    (each ``&&``-joined part on its own) and in its inline code spans."""

    def commands(number: int, text: str) -> Iterator[DocCommand]:
        for part in text.split("&&"):
            part = part.strip()
            if START.match(part):
                where = f"{path.relative_to(ROOT)}:{number}"
                words = tuple(shlex.split(part))
                yield DocCommand(where, words)
                for timed in timed_commands(words):
                    if START.match(shlex.join(timed)):
                        yield DocCommand(f"{where} (timed)", timed)

    block: list[tuple[int, str]] | None = None
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        if line.strip().startswith("```"):
            if block is not None:
                for start, text in _logical_lines(block):
                    yield from commands(start, text)
            block = [] if block is None else None
        elif block is not None:
            block.append((number, line))
        else:
            for span in INLINE_CODE.finditer(line):
                yield from commands(number, span.group(1))


def _all_commands() -> list[DocCommand]:
    pages = [p for p in _tracked_text_files() if p.suffix == ".md"]
    return [c for page in pages for c in doc_commands(page)]


def _entry(words: Sequence[str], monkeypatch: pytest.MonkeyPatch
           ) -> tuple[Callable[[list[str]], Any], list[str]]:
    """The function a command runs and its argument list, without ``VAR=`` and timer words (a
    script whose ``main()`` reads ``sys.argv`` gets them there)."""
    words = list(words)
    while words and re.match(r"^[A-Z_]+=", words[0]):
        words.pop(0)
    if words and words[0] == "/usr/bin/time":
        words.pop(0)
        while words[0].startswith("-"):
            words.pop(0)
    for end in ("|", ">", "2>"):
        if end in words:
            words = words[:words.index(end)]
    if words[0] == "mivecc":
        from mivecc_agents.cli import main

        return main, words[1:]
    name = Path(words[1]).stem
    main = load_benchmark(name, f"doc_command_{name}").main
    if inspect.signature(main).parameters:
        return main, words[2:]
    monkeypatch.setattr(sys, "argv", words[1:])
    return lambda argv: main(), words[2:]


def parsed_options(command: DocCommand, monkeypatch: pytest.MonkeyPatch) -> argparse.Namespace:
    """The options ``command`` parses to; fails the test with its parser's message if it does
    not parse."""
    stop_after_parsing(monkeypatch)
    monkeypatch.setattr(cli_args, "existing_file", Path)  # files of earlier runs: not here
    run, argv = _entry(command.words, monkeypatch)
    errors = io.StringIO()
    try:
        with contextlib.redirect_stderr(errors):
            status = run(argv)
    except ParsedError as parsed:
        return parsed.args[0]
    except SystemExit as exc:
        status = exc.code
    pytest.fail(f"{command.where}: `{' '.join(command.words)}` does not parse (status "
                f"{status}): {errors.getvalue().strip()}")


def check_values(options: argparse.Namespace) -> None:
    """What the parsers leave to later code: ``mivecc train``'s checks before training and
    every ``--set`` field (raises ``ConfigError`` naming the bad one)."""
    from mivecc_agents import train_checks
    from mivecc_agents.cli import config_overrides_from_args, parse_set_items

    command = getattr(options, "command", None)
    if command == "train":
        with pytest.MonkeyPatch.context() as patch:  # --out folders are not made here
            patch.setattr(train_checks, "_check_out_dir", lambda out: None)
            train_checks.check_train_args(options)
    elif command == "evaluate":
        from_overrides(None, **config_overrides_from_args(options))
    elif getattr(options, "set_items", None):
        from_overrides(None, **parse_set_items(options.set_items))


COMMANDS = _all_commands()


def test_the_docs_yield_enough_commands() -> None:
    checked = [c for c in COMMANDS if c.checkable]
    assert len(checked) >= MIN_CHECKED, (len(checked), len(COMMANDS))


def test_extraction_joins_continuations_and_cuts_comments(tmp_path: Path) -> None:
    page = tmp_path / "page.md"
    page.write_text("text\n```bash\n# a comment\nmivecc evaluate --scheme E \\\n    --seeds 0 1"
                    "   # 5 s\npip install x && python benchmarks/speed.py --rounds 2\n"
                    "echo mivecc\n```\nmivecc outside a block; `mivecc fields --help` inline and "
                    "`python benchmarks/table_diff.py` by name\n", encoding="utf-8")
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr("tests.test_doc_commands.ROOT", tmp_path)
        found = list(doc_commands(page))
    assert [(c.where, c.words) for c in found] == [
        ("page.md:4", ("mivecc", "evaluate", "--scheme", "E", "--seeds", "0", "1")),
        ("page.md:6", ("python", "benchmarks/speed.py", "--rounds", "2")),
        ("page.md:9", ("mivecc", "fields", "--help")),
        ("page.md:9", ("python", "benchmarks/table_diff.py")),
    ]
    assert found[-1].is_name and not found[-1].checkable
    assert DocCommand("x", ("mivecc", "train", "--seed", "$s")).is_pattern


def test_a_timed_command_yields_the_commands_it_times(tmp_path: Path) -> None:
    page = tmp_path / "page.md"
    page.write_text("```bash\npython benchmarks/time_commands.py -n 2 --vs \"mivecc evaluate "
                    "--seed 1\" -- python benchmarks/speed.py --quick\n```\n", encoding="utf-8")
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr("tests.test_doc_commands.ROOT", tmp_path)
        found = [(c.where, c.words[:3]) for c in doc_commands(page)]
    assert found == [("page.md:2", ("python", "benchmarks/time_commands.py", "-n")),
                     ("page.md:2 (timed)", ("python", "benchmarks/speed.py", "--quick")),
                     ("page.md:2 (timed)", ("mivecc", "evaluate", "--seed"))]


def test_a_bad_option_fails_the_check(monkeypatch: pytest.MonkeyPatch) -> None:
    """The check can fail: an unknown option, and a --set value out of range."""
    with pytest.raises(pytest.fail.Exception, match="does not parse"):
        parsed_options(DocCommand("x", ("mivecc", "evaluate", "--no-such-option")), monkeypatch)
    options = parsed_options(
        DocCommand("x", ("python", "benchmarks/paper_table.py", "--set", "omega=7")), monkeypatch)
    with pytest.raises(ValueError, match="omega"):
        check_values(options)


@pytest.mark.parametrize("command", [c for c in COMMANDS if c.checkable],
                         ids=lambda c: c.where)
def test_documented_command_parses(command: DocCommand, monkeypatch: pytest.MonkeyPatch) -> None:
    check_values(parsed_options(command, monkeypatch))
