"""The documentation site's structure: every CLI command has its reference page, every guide is in the nav.

The strict build itself (``mkdocs build --strict``: broken links, pages missing from the nav) runs in
``scripts/test`` before pytest. These checks read ``mkdocs.yml`` and the hook that makes the CLI reference
(``docs/hooks.py``), without building, so they need neither mkdocs nor a browser.
"""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import typer
import yaml

from jcalib.app.cli import app

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
GUIDES = ["camera", "stereo", "eye-in-hand", "eye-to-hand", "camera-tcp", "pivot-tracker", "two-robots",
          "kinematics", "zoom", "planning", "error-budget", "import", "operator-app"]
FORMATS = ["cell", "observations", "result", "session", "station", "plan"]


def _hooks():
    spec = importlib.util.spec_from_file_location("jcalib_docs_hooks", DOCS / "hooks.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _config() -> dict:
    # mkdocs.yml holds no YAML tags (no !ENV, no !!python): the safe loader reads it.
    return yaml.safe_load((ROOT / "mkdocs.yml").read_text(encoding="utf-8"))


def _pages(nav) -> list[str]:
    """Every page path of a nav (nested lists and single-key mappings)."""
    if isinstance(nav, str):
        return [nav]
    if isinstance(nav, list):
        return [p for item in nav for p in _pages(item)]
    if isinstance(nav, dict):
        return [p for value in nav.values() for p in _pages(value)]
    return []


def test_every_cli_command_has_a_reference_page_in_the_nav():
    commands = list(typer.main.get_command(app).commands)
    hooks = _hooks()
    helps = hooks.command_help()
    assert list(helps) == commands
    nav = _pages(hooks._expand(_config()["nav"], commands))
    for name in commands:
        assert f"reference/cli/{name}.md" in nav, name
        page = hooks.command_page(name, helps[name])
        assert f"Usage: jcalib {name}" in page, name
    index = hooks.index_page(helps)
    assert all(f"({name}.md)" in index for name in commands)


def test_command_help_is_plain_text_at_a_fixed_width():
    helps = _hooks().command_help()
    for name, text in helps.items():
        assert not re.search(r"[╭╰│]|\x1b\[", text), name  # click's formatting, not rich's boxes or colours
        assert max(len(line) for line in text.splitlines()) <= 100, name


def test_every_guide_and_reference_page_is_in_the_nav_and_exists():
    nav = _pages(_config()["nav"])
    expected = ([f"guides/{g}.md" for g in GUIDES] + [f"reference/formats/{f}.md" for f in FORMATS]
                + ["index.md", "getting-started.md", "conventions.md", "real-cell.md", "reference/api.md", "design.md"])
    for page in expected:
        assert page in nav, page
        assert (DOCS / page).is_file(), page
    on_disk = {p.relative_to(DOCS).as_posix() for p in (DOCS / "guides").glob("*.md")}
    assert on_disk == {f"guides/{g}.md" for g in GUIDES}


def test_the_api_page_documents_every_public_name():
    import jcalib

    text = (DOCS / "reference" / "api.md").read_text(encoding="utf-8")
    for name in jcalib.__all__:
        if name != "__version__":
            assert f"heading: jcalib.{name}\n" in text, name


def test_docs_refer_to_nothing_outside_the_repository():
    files = [*DOCS.rglob("*.md"), DOCS / "hooks.py", ROOT / "mkdocs.yml", ROOT / "README.md"]
    for path in files:
        text = path.read_text(encoding="utf-8")
        for phrase in ("shared folder", "../shared", "DESIGN" + ".md"):
            assert phrase not in text, (path, phrase)
