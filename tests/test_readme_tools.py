"""The README's command tables list every `courtloc` verb the parser has, and no verb it does not have."""
from __future__ import annotations

import argparse
import re
from pathlib import Path

from courtloc.cli import build_parser

README = Path(__file__).resolve().parents[1] / "README.md"


def parser_verbs(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()) -> set[tuple[str, ...]]:
    """Every leaf command as its words: ('bench', 'paper'), ('monitor',) ..."""
    groups = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not groups:
        return {path}
    # a group with options of its own runs on its own too (`calibrate --data ...` beside `calibrate mount`)
    own_options = [a for a in parser._actions if a.option_strings and a.dest != "help"]
    itself = {path} if path and own_options else set()
    return itself | {verb for group in groups for name, child in group.choices.items()
                     for verb in parser_verbs(child, (*path, name))}


def readme_verbs(text: str, groups: set[str]) -> set[tuple[str, ...]]:
    """Verbs named in the first cell of a table row: `courtloc VERB [SUB|SUB...] ARGS` (pipes escaped)."""
    found = set()
    for cell in re.findall(r"^\| `courtloc ([^`]+)`", text, flags=re.M):
        words = cell.replace("\\|", "|").split()
        if words[0] in groups and len(words) > 1 and not words[1].startswith("-"):
            found |= {(words[0], sub) for sub in words[1].split("|")}
        else:
            found.add((words[0],))
    return found


def test_the_readme_tables_list_every_verb() -> None:
    verbs = parser_verbs(build_parser())
    groups = {v[0] for v in verbs if len(v) > 1}
    listed = readme_verbs(README.read_text(encoding="utf-8"), groups)
    assert verbs - listed == set(), "verbs the README's tables do not list"
    assert listed - verbs == set(), "README rows naming verbs that do not exist"
    assert ("bench", "paper") in listed and ("localizer", "residuals") in listed  # the parse reads the pipes
