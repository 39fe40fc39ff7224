"""Layout rules that import-linter cannot state: no module of jcalib uses another module's private names.

A ``_name`` is private to the module that defines it: another module that imports it
(``from jcalib.a import _name``, in any form, at any depth, relative or absolute) or reaches it through
a module it imported (``from jcalib import a`` then ``a._name``) is coupled to an implementation
detail. Make the name public where it belongs, or move the caller. Found by parsing every module
with ``ast``, so multi-line and function-local imports count too; dunder names (``__version__``)
are public.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "jcalib"

#: Uses that other work in progress removes: (module, the module reached, the name) -> why it is here.
#: Each entry must still occur (the test below fails when one is fixed, so the list only shrinks).
KNOWN: dict[tuple[str, str, str], str] = {}


def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _is_module(name: str) -> bool:
    rel = Path(*name.split("."))
    return (ROOT / rel).with_suffix(".py").is_file() or (ROOT / rel / "__init__.py").is_file()


def _private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def _absolute(node: ast.ImportFrom, module: str, is_package: bool) -> str:
    if node.level == 0:
        return node.module or ""
    base = module.split(".")
    base = base[: len(base) - node.level + (1 if is_package else 0)]
    return ".".join(base + ([node.module] if node.module else []))


def private_uses(path: Path) -> set[tuple[str, str, str, int]]:
    """``(module, module reached, private name, line)`` for every private name ``path`` takes from
    another jcalib module."""
    module = _module_name(path)
    tree = ast.parse(path.read_text(), filename=str(path))
    found: set[tuple[str, str, str, int]] = set()
    aliases: dict[str, str] = {}  # local name -> jcalib module it is bound to
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            source = _absolute(node, module, path.name == "__init__.py")
            if source.split(".")[0] != "jcalib":
                continue
            for alias in node.names:
                if _private(alias.name):
                    found.add((module, source, alias.name, node.lineno))
                elif _is_module(f"{source}.{alias.name}"):
                    aliases[alias.asname or alias.name] = f"{source}.{alias.name}"
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] == "jcalib":
                    if alias.asname:
                        aliases[alias.asname] = alias.name
                    else:
                        aliases["jcalib"] = "jcalib"
    for node in ast.walk(tree):
        if not isinstance(node, ast.Attribute):
            continue
        chain = [node.attr]
        base = node.value
        while isinstance(base, ast.Attribute):
            chain.append(base.attr)
            base = base.value
        if not isinstance(base, ast.Name) or base.id not in aliases:
            continue
        # walk ``alias.sub.module._name`` down to the first name that is not a module
        target = aliases[base.id]
        for attr in reversed(chain):
            if _private(attr) and target != module:
                found.add((module, target, attr, node.lineno))
                break
            if not _is_module(f"{target}.{attr}"):
                break
            target = f"{target}.{attr}"
    return found


def _all_uses() -> set[tuple[str, str, str, int]]:
    return set().union(*(private_uses(p) for p in sorted(PACKAGE.rglob("*.py"))))


def test_no_module_uses_another_modules_private_names():
    uses = sorted(u for u in _all_uses() if u[:3] not in KNOWN)
    assert not uses, "private names used across modules (make them public where they belong):\n" + "\n".join(
        f"  {m} line {line}: {name} of {src}" for m, src, name, line in uses
    )


def test_the_known_exceptions_still_exist():
    seen = {u[:3] for u in _all_uses()}
    stale = sorted(k for k in KNOWN if k not in seen)
    assert not stale, f"fixed, remove from KNOWN in {Path(__file__).name}: {stale}"


@pytest.mark.parametrize(
    "source, expected",
    [
        ("from jcalib.geometry.lie import _k, local\n", {("jcalib.geometry.lie", "_k")}),
        ("from jcalib.geometry.lie import (\n    local,\n    _se3_log,\n)\n", {("jcalib.geometry.lie", "_se3_log")}),
        ("def f():\n    from ..geometry.se3 import _x\n", {("jcalib.geometry.se3", "_x")}),
        ("from . import _helpers\n", {("jcalib.init", "_helpers")}),
        ("from jcalib.geometry import lie\nlie._se3_log(1)\n", {("jcalib.geometry.lie", "_se3_log")}),
        ("import jcalib.geometry.lie as L\nL._f\n", {("jcalib.geometry.lie", "_f")}),
        ("import jcalib.geometry.lie\njcalib.geometry.lie._g\n", {("jcalib.geometry.lie", "_g")}),
        ("from jcalib import __version__\nfrom jcalib.geometry.se3 import invert\nimport numpy as np\nnp._x\n", set()),
        ("from jcalib.geometry import lie\nlie.__name__\n", set()),
    ],
)
def test_the_check_finds_every_form(tmp_path, monkeypatch, source, expected):
    """The check itself: each way of reaching a private name is found, public and dunder names are not."""
    fake = tmp_path / "jcalib" / "init" / "probe.py"
    fake.parent.mkdir(parents=True)
    for pkg in ("jcalib", "jcalib/init", "jcalib/geometry"):
        (tmp_path / pkg / "__init__.py").parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / pkg / "__init__.py").write_text("")
    for mod in ("geometry/lie.py", "geometry/se3.py"):
        (tmp_path / "jcalib" / mod).write_text("")
    fake.write_text(source)
    monkeypatch.setitem(globals(), "ROOT", tmp_path)
    assert {(src, name) for _, src, name, _ in private_uses(fake)} == expected
