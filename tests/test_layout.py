"""The floor plan (docs/layout.md): no import cycles, the core's layer rule, and a layout page that
matches the tree. Each rule is a function over a package folder, run on the real package and on a
small package written into tmp_path that breaks it (so the rule can fail)."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import sara_app

PACKAGE = Path(sara_app.__file__).resolve().parent
LAYOUT = PACKAGE.parent / "docs" / "layout.md"
CORE = ("geometry", "human", "robot", "safety")
VOCABULARY = ("sara_app", "sara_app.errors", "sara_app.settings", "sara_app.kernel_types")


def _modules(root: Path) -> dict[str, Path]:
    out = {}
    for p in root.rglob("*.py"):
        parts = [root.name, *p.relative_to(root).with_suffix("").parts]
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = p
    return out


def import_graph(root: Path) -> dict[str, set[str]]:
    """Module -> the package's modules it imports, at any depth of the file (imports inside
    functions and under TYPE_CHECKING count: they are dependencies too)."""
    mods = _modules(root)
    graph: dict[str, set[str]] = {}
    for name, path in mods.items():
        deps = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                targets = [f"{node.module}.{a.name}" for a in node.names]
                deps |= {t if t in mods else node.module for t in targets}
            elif isinstance(node, ast.Import):
                deps |= {a.name for a in node.names}
        graph[name] = {d for d in deps if d in mods and d != name}
    return graph


def import_cycles(root: Path) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan, iterative)."""
    graph = import_graph(root)
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    cycles = []
    for start in graph:
        if start in index:
            continue
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            v, it = work[-1]
            for w in it:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                    break
                if w in on_stack:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    comp = []
                    while True:
                        w = stack.pop()
                        on_stack.discard(w)
                        comp.append(w)
                        if w == v:
                            break
                    if len(comp) > 1:
                        cycles.append(sorted(comp))
    return cycles


def layer_violations(root: Path) -> list[str]:
    """Imports from a core folder to anything outside the core and the root's vocabulary."""
    pkg = root.name
    core = tuple(f"{pkg}.{c}" for c in CORE)
    vocabulary = {v.replace("sara_app", pkg, 1) for v in VOCABULARY}

    def in_core(m: str) -> bool:
        return any(m == c or m.startswith(c + ".") for c in core)

    out = []
    for mod, deps in import_graph(root).items():
        if in_core(mod):
            out += [f"{mod} -> {d}" for d in sorted(deps) if not (in_core(d) or d in vocabulary)]
    return out


def layout_mismatches(root: Path, page: str) -> list[str]:
    """Folders and root modules the page does not name, and paths it names that do not exist."""
    named = set(re.findall(r"\b" + root.name + r"/([A-Za-z0-9_]+(?:/|\.py))", page))
    present = {p.name + "/" for p in root.iterdir() if p.is_dir() and p.name != "__pycache__"}
    present |= {p.name for p in root.glob("*.py") if p.name != "__init__.py"}
    return [f"not in the layout page: {root.name}/{x}" for x in sorted(present - named)] + [
        f"named but absent: {root.name}/{x}" for x in sorted(named - present)
    ]


def mode_switches(root: Path, modes: tuple[str, ...] = ("ssm", "pfl", "jssa")) -> list[str]:
    """Comparisons with a safety mode's name outside safety/ (and the benchmarks, which pick the
    mode to build): what a mode does or shows is asked of safety.settings.mode_facts instead."""
    out = []
    for mod, path in _modules(root).items():
        if mod.split(".")[1:2] in (["safety"], ["bench"]):
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if not isinstance(node, ast.Compare):
                continue
            for side in (node.left, *node.comparators):
                values = side.elts if isinstance(side, (ast.Tuple, ast.List, ast.Set)) else [side]
                if any(isinstance(v, ast.Constant) and v.value in modes for v in values):
                    out.append(f"{mod}:{node.lineno}")
    return out


def test_the_package_has_no_import_cycles() -> None:
    assert import_cycles(PACKAGE) == []


def test_the_core_imports_only_the_core_and_the_shared_vocabulary() -> None:
    assert layer_violations(PACKAGE) == []


def test_no_switch_on_the_safety_mode_outside_safety() -> None:
    assert mode_switches(PACKAGE) == []


def test_the_layout_page_names_every_folder_and_root_module() -> None:
    assert layout_mismatches(PACKAGE, LAYOUT.read_text()) == []


def _package(tmp_path: Path, files: dict[str, str]) -> Path:
    root = tmp_path / "sara_app"
    for rel, text in files.items():
        p = root / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text)
    return root


def test_the_rules_fail_on_a_cycle_an_io_import_a_mode_switch_and_an_undocumented_folder(
    tmp_path: Path,
) -> None:
    root = _package(
        tmp_path,
        {
            "__init__.py": "",
            "errors.py": "",
            "safety/__init__.py": "",
            "safety/a.py": "from sara_app.safety import b\n",
            "safety/b.py": "def f():\n    from sara_app.safety.a import g  # in a function\n",
            "safety/c.py": "from sara_app.bus.messages import X\n",
            "bus/__init__.py": "",
            "bus/messages.py": "X = 1\n",
            "newfolder/__init__.py": "",
            "newfolder/show.py": "def f(m):\n    return m in ('ssm', 'pfl')\n",
            "safety/modes.py": "def build(m):\n    return m == 'pfl'\n",
        },
    )
    assert import_cycles(root) == [["sara_app.safety.a", "sara_app.safety.b"]]
    assert layer_violations(root) == ["sara_app.safety.c -> sara_app.bus.messages"]
    assert mode_switches(root) == ["sara_app.newfolder.show:2"]
    page = "sara_app/errors.py sara_app/safety/ sara_app/bus/ sara_app/gone.py"
    assert layout_mismatches(root, page) == [
        "not in the layout page: sara_app/newfolder/",
        "named but absent: sara_app/gone.py",
    ]
