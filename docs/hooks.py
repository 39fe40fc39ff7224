"""MkDocs hook: the CLI reference, a page per ``jcalib`` command with its ``--help`` text, made at build time;
and the examples, a page per folder of ``examples/`` (its README.md and cell spec), so that the guides link
to the very commands and files that ``tests/test_examples.py`` runs.

The pages come from the typer app itself (``jcalib.app.cli.app``, its click commands), so they cannot go
stale: a new command gets its page and its nav entry, a changed option its new help. ``on_config`` expands
the nav entry ``reference/cli/index.md`` into a section (the index, then one page per command, in the
app's order); ``on_files`` adds the generated pages. The help is click's plain formatting (no rich boxes)
at a fixed width of 100 columns, so a build does not depend on the terminal.
"""

from __future__ import annotations

import sys
from pathlib import Path

INDEX = "reference/cli/index.md"
WIDTH = 100
EXAMPLES_INDEX = "examples/index.md"
EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def example_names() -> list[str]:
    """The example folders (those with a README.md), sorted."""
    return sorted(p.name for p in EXAMPLES.iterdir() if (p / "README.md").is_file())


def example_page(name: str) -> str:
    """An example's page: its README.md, then its cell spec."""
    d = EXAMPLES / name
    cell = (d / "cell.yaml").read_text(encoding="utf-8").rstrip()
    readme = (d / "README.md").read_text(encoding="utf-8").rstrip()
    return (f"{readme}\n\nFiles in `examples/{name}/`: `cell.yaml` (below), `observations.json`, `expected.json` "
            "(the simulation's truth, which `tests/test_examples.py` compares the result with).\n\n"
            f"```yaml\n{cell}\n```\n")


def _app_command():
    """The click group of ``jcalib`` (the repository's own package, not an installed copy)."""
    root = str(Path(__file__).resolve().parents[1])
    if root not in sys.path:
        sys.path.insert(0, root)
    import typer

    from jcalib.app.cli import app

    return typer.main.get_command(app)


def command_help() -> dict[str, str]:
    """Command name -> its ``jcalib NAME --help`` text (plain, ``WIDTH`` columns), in the app's order."""
    group = _app_command()
    parent = group.make_context("jcalib", [], resilient_parsing=True, terminal_width=WIDTH, max_content_width=WIDTH)
    out = {}
    for name, command in group.commands.items():
        command.rich_markup_mode = None  # click's plain help; rich's escapes (\[) are undone below
        ctx = command.make_context(name, [], parent=parent, resilient_parsing=True,
                                   terminal_width=WIDTH, max_content_width=WIDTH)
        out[name] = command.get_help(ctx).replace("\\[", "[")
    return out


def _summary(text: str) -> str:
    """The first paragraph after the usage line, on one line."""
    paragraphs = [p.strip() for p in text.split("\n\n")]
    return " ".join(paragraphs[1].split()) if len(paragraphs) > 1 else ""


def _cell(text: str) -> str:
    """``text`` for a Markdown table cell."""
    return text.replace("|", "\\|")


def command_page(name: str, text: str) -> str:
    return (f"# jcalib {name}\n\n{_summary(text)}\n\n"
            f"Generated at build time from `jcalib {name} --help`; exit statuses are on the "
            f"[CLI reference](index.md) page.\n\n```text\n{text.rstrip()}\n```\n")


def index_page(helps: dict[str, str]) -> str:
    rows = "\n".join(f"| [`jcalib {name}`]({name}.md) | {_cell(_summary(text))} |" for name, text in helps.items())
    return ("# CLI reference\n\n"
            "Every command of `jcalib` (`.venv/bin/jcalib` after `./scripts/setup`), each page its `--help` text, "
            "generated from the command line itself when the site is built.\n\n"
            f"| command | does |\n|---|---|\n{rows}\n\n"
            "Exit status: 0 success, 2 bad input or a mistyped option (a one-paragraph message, no traceback), "
            "3 the data cannot determine the unknowns (named), 4 a device error (a capture says how to resume), "
            "130 interrupted. `jcalib compare` and `jcalib cross-validate` exit 1 when the calibrations differ. "
            "`JCALIB_DEBUG=1` shows the traceback of an unexpected error.\n")


def _expand(nav, names, examples=()):
    """``nav`` with the entry ``INDEX`` replaced by a section: the index, then each command's page (and
    ``EXAMPLES_INDEX`` by the examples' index, then each example's page)."""
    if isinstance(nav, list):
        return [_expand(item, names, examples) for item in nav]
    if isinstance(nav, dict):
        out = {}
        for title, value in nav.items():
            if value == INDEX:
                value = [INDEX, *({f"jcalib {n}": f"reference/cli/{n}.md"} for n in names)]
            elif value == EXAMPLES_INDEX:
                value = [EXAMPLES_INDEX, *({n: f"examples/{n}.md"} for n in examples)]
            out[title] = _expand(value, names, examples)
        return out
    return nav


def on_config(config, **kwargs):
    config["nav"] = _expand(config["nav"], list(command_help()), example_names())
    return config


def on_files(files, config, **kwargs):
    from mkdocs.structure.files import File

    helps = command_help()
    files.append(File.generated(config, INDEX, content=index_page(helps)))
    for name, text in helps.items():
        files.append(File.generated(config, f"reference/cli/{name}.md", content=command_page(name, text)))
    files.append(File.generated(config, EXAMPLES_INDEX, content=(EXAMPLES / "README.md").read_text(encoding="utf-8")))
    for name in example_names():
        files.append(File.generated(config, f"examples/{name}.md", content=example_page(name)))
    return files
