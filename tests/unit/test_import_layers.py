"""The package's import graph runs one way: each package imports only from lower layers.

Walks every module of pospp with ``ast`` (imports inside functions and ``TYPE_CHECKING``
blocks count too) and checks each import of another pospp package against ``LAYERS`` (issue
17: io, sim, nav, calib, diagnose, report each import only downward; io imports nothing of sim;
nothing below io imports io). Packages in the same layer do not import each other.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[2] / "pospp"
ARCHITECTURE_DOC = PACKAGE.parent / "docs" / "architecture.md"

LAYERS: tuple[frozenset[str], ...] = (
    # the data contract and the small facts
    frozenset({"pospp", "types", "units", "earth", "rotation", "threads", "memory",
               "distributions", "config_schema"}),
    # files <-> contract; the navigation core
    frozenset({"io", "nav"}),
    # stage results -> table columns (names the result types of io and nav)
    frozenset({"outputs"}),
    # the stages' numeric layer over nav
    frozenset({"sim", "calib", "qc", "evaluate", "effects_catalog"}),
    frozenset({"diagnose", "simcompare", "report"}),
    frozenset({"config"}),
    frozenset({"flight_stages"}),
    frozenset({"null_stage"}),
    frozenset({"sensor_stage"}),
    frozenset({"diagnosis_stage", "lever_time_stage"}),
    frozenset({"pipeline", "convert", "api"}),
    frozenset({"batch", "compare_sim"}),
    frozenset({"cli"}),
)


FACADE = {"api", "pipeline", "config"}
"""What the package module ``pospp/__init__.py`` may name above its layer: the public API it
re-exports (the readers, ``process_flight`` and its configuration), imported at first access
(``pospp.__getattr__``) or for type checkers only (docs/architecture.md)."""


def _layer_of(top: str) -> int:
    for i, layer in enumerate(LAYERS):
        if top in layer:
            return i
    raise AssertionError(f"pospp.{top} is in no layer of LAYERS; add it")


def _top(module: str) -> str:
    """'pospp.io.mcap_reader' -> 'io'; 'pospp' -> 'pospp'."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "pospp"


def _imports(path: Path) -> list[tuple[int, str]]:
    """(line, imported pospp module) of every import statement in one file."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module \
                and node.module.split(".")[0] == "pospp":
            if node.module == "pospp":  # from pospp import earth, __version__
                out += [(node.lineno, f"pospp.{a.name}" if not a.name.startswith("__")
                         else "pospp") for a in node.names]
            else:
                out.append((node.lineno, node.module))
        elif isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names if a.name.split(".")[0] == "pospp"]
    return out


def _modules() -> list[Path]:
    return sorted(PACKAGE.rglob("*.py"))


def test_every_package_is_in_a_layer() -> None:
    tops = {_top(".".join(("pospp", *p.relative_to(PACKAGE).with_suffix("").parts)))
            for p in _modules()}
    tops.discard("__init__")
    missing = sorted(t for t in tops if not any(t in layer for layer in LAYERS))
    assert not missing, f"packages in no layer: {missing}"


@pytest.mark.parametrize("path", _modules(), ids=lambda p: str(p.relative_to(PACKAGE)))
def test_imports_run_downward(path: Path) -> None:
    rel = path.relative_to(PACKAGE).with_suffix("").parts
    own = "pospp" if rel == ("__init__",) else rel[0]
    own_layer = _layer_of(own)
    bad = []
    for line, module in _imports(path):
        top = _top(module)
        if top == own or (rel == ("__init__",) and top in FACADE):
            continue
        if _layer_of(top) >= own_layer:
            bad.append(f"line {line}: {module} (layer {_layer_of(top)}; {own} is layer "
                       f"{own_layer})")
    assert not bad, f"{path.relative_to(PACKAGE)} imports upward or sideways: {bad}"


def test_architecture_doc_lists_the_layers() -> None:
    """docs/architecture.md's layer table is ``LAYERS``, in order (the doc describes the house
    the test enforces)."""
    rows = re.findall(r"^\| (\d+) \| ([^|]+) \|", ARCHITECTURE_DOC.read_text(), re.MULTILINE)
    doc = [frozenset(re.findall(r"`(\w+)`", names)) for _, names in rows]
    assert [int(n) for n, _ in rows] == list(range(len(rows)))
    assert doc == list(LAYERS), (
        f"docs/architecture.md layers {[sorted(d) for d in doc]} != LAYERS "
        f"{[sorted(x) for x in LAYERS]}")
