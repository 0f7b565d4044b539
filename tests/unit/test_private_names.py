"""No module of pospp uses another module's private names.

A name that starts with one underscore is private to its module: another pospp module may not
import it (``from pospp.calib.reml import _gls``) nor reach it through a module it imported
(``pipeline._render_report``). A helper two modules need is public in the module where it
belongs, with a docstring stating its contract; a helper one module needs lives there.

Private *modules* are fine inside their own package: ``from pospp.nav import _kernels`` in
``pospp/nav/strapdown.py`` (the compiled kernels of the public module beside them). Dunders
(``__version__``) are not private names. The scan is ``ast`` over every module of pospp,
imports inside functions and ``TYPE_CHECKING`` blocks included.
"""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[2] / "pospp"

ALLOWED: dict[tuple[str, str], str] = {}
"""(importing file relative to pospp/, used private name) -> why it is still there. Each
entry must still occur (a stale entry fails the test): remove it with the fix."""


def _is_private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def _module_names(package: Path) -> dict[str, str]:
    """Dotted module name -> path relative to ``package`` of every module and package."""
    out = {}
    for p in package.rglob("*.py"):
        rel = p.relative_to(package)
        parts = (package.name, *rel.with_suffix("").parts)
        out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = rel.as_posix()
    return out


def _package_of(rel: str, root: str) -> str:
    """'nav/strapdown.py' -> 'pospp.nav'; 'nav/__init__.py' -> 'pospp.nav'."""
    parts = (root, *Path(rel).parts[:-1])
    return ".".join(parts)


def private_uses(source: str, rel: str, modules: dict[str, str], root: str = "pospp"
                 ) -> list[tuple[int, str]]:
    """(line, dotted private name) of each private name of another module used by the module
    ``rel`` whose text is ``source``. A private submodule imported inside its own package
    (the importing module's package is, or is inside, the submodule's parent) is not one."""
    own = ".".join((root, *Path(rel).with_suffix("").parts)).removesuffix(".__init__")
    package = _package_of(rel, root)

    def crosses(full: str) -> bool:
        if full in modules:  # a private module: fine within its own package
            parent = full.rsplit(".", 1)[0]
            return not (package == parent or package.startswith(parent + "."))
        return full.rsplit(".", 1)[0] != own

    tree = ast.parse(source, rel)
    found: list[tuple[int, str]] = []
    bound: dict[str, str] = {}  # local name -> pospp module it stands for
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module \
                and node.module.split(".")[0] == root:
            for a in node.names:
                full = f"{node.module}.{a.name}"
                if full in modules:
                    bound[a.asname or a.name] = full
                if _is_private(a.name) and crosses(full):
                    found.append((node.lineno, full))
        elif isinstance(node, ast.Import):
            for a in node.names:
                if a.name.split(".")[0] != root:
                    continue
                if a.asname:
                    bound[a.asname] = a.name
                for i, part in enumerate(a.name.split(".")):
                    full = ".".join(a.name.split(".")[:i + 1])
                    if _is_private(part) and crosses(full):
                        found.append((node.lineno, full))
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) \
                and node.value.id in bound and _is_private(node.attr):
            full = f"{bound[node.value.id]}.{node.attr}"
            if crosses(full):
                found.append((node.lineno, full))
    return found


def _scan(package: Path) -> dict[tuple[str, str], list[int]]:
    modules = _module_names(package)
    out: dict[tuple[str, str], list[int]] = {}
    for rel in sorted(modules.values()):
        for line, name in private_uses((package / rel).read_text(), rel, modules, package.name):
            out.setdefault((rel, name), []).append(line)
    return out


def test_no_private_name_is_used_across_modules():
    uses = _scan(PACKAGE)
    offenders = [f"pospp/{rel}:{lines[0]}: {name}" for (rel, name), lines in sorted(uses.items())
                 if (rel, name) not in ALLOWED]
    assert not offenders, (
        "private names of another module used (make the helper public where it belongs, with "
        "a docstring, or move it to its one user):\n" + "\n".join(offenders))
    stale = sorted(set(ALLOWED) - set(uses))
    assert not stale, f"ALLOWED entries no longer used (remove them): {stale}"


MODULES = {"pospp.calib.reml": "calib/reml.py", "pospp.calib": "calib/__init__.py",
           "pospp.calib._null_kernel": "calib/_null_kernel.py", "pospp.nav": "nav/__init__.py",
           "pospp.nav._kernels": "nav/_kernels.py", "pospp.pipeline": "pipeline.py",
           "pospp.calib.solve": "calib/solve.py", "pospp": "__init__.py"}


def test_the_scan_names_each_kind_of_private_use():
    """Each form is caught, and the allowed forms are not (the scan itself can fail)."""
    src = ("from pospp.calib.reml import _gls, fit\n"
           "from pospp import pipeline\n"
           "import pospp.nav._kernels as k\n"
           "def f():\n"
           "    from pospp.calib import _null_kernel\n"
           "    return pipeline._render(), pipeline.run(), k.radii, fit._x\n")
    got = private_uses(src, "calib/solve.py", MODULES)
    assert got == [(1, "pospp.calib.reml._gls"), (3, "pospp.nav._kernels"),
                   (6, "pospp.pipeline._render")]
    own = "from pospp.calib import _null_kernel\nfrom pospp import __version__\n"
    assert private_uses(own, "calib/linear_null.py", MODULES) == []
    assert private_uses("from pospp.calib import _null_kernel\n", "nav/x.py", MODULES) == \
        [(1, "pospp.calib._null_kernel")]
