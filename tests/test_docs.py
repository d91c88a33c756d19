"""The README and docs/ stay a guide that runs: every command block parses, names real subcommands and
flags, and the README keeps to its length. (``make readme-check`` runs the blocks themselves.)"""
from __future__ import annotations

import importlib.util
import shlex
from pathlib import Path

import pytest

from deepslam.cli import build_parser

REPO = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("readme_check", REPO / "scripts" / "readme_check.py")
readme_check = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(readme_check)


def test_readme_is_a_short_guide_without_history():
    text = (REPO / "README.md").read_text()
    assert len(text.splitlines()) <= 300
    for word in ("session", "shipped until", "shipped since"):
        assert word not in text.lower(), word


@pytest.mark.parametrize("page", readme_check.pages(), ids=lambda p: p.name)
def test_every_deepslam_command_in_the_docs_parses(page):
    """Each ``deepslam SUBCOMMAND ...`` line of a sh block is accepted by the real argument parser."""
    parser = build_parser()
    for kind, code, _ in readme_check.blocks(page):
        if kind != "sh":
            continue
        lex = shlex.shlex(code, posix=True, punctuation_chars=";&|")
        lex.whitespace_split, lex.commenters = True, "#"
        tokens, parts = list(lex), [[]]
        for t in tokens:
            if set(t) <= set(";&|"):
                parts.append([])
            else:
                parts[-1].append(t)
        for words in parts:
            part = " ".join(words)
            while words and "=" in words[0] and not words[0].startswith("-"):
                words = words[1:]  # VAR=value prefixes
            if not words or words[0] != "deepslam":
                continue
            try:
                parser.parse_args(words[1:])
            except SystemExit as e:
                pytest.fail(f"{page.name}: `{part}` is refused by the parser (exit {e.code})")
