"""The package's layers: the physics core never imports the orchestration, and the study modules import each
other without a circle.

The core is the chain design -> geometry -> mesh -> mechanics -> electrics and the coupled model that runs it, with
the layouts, conductivity and touches. Downstream stages (the sensor-model export, reconstruction, gestures) run
their parallel work through :mod:`latticeopt.execution`, beside the core, not through the study package.

Two checks: one imports the core in a fresh interpreter and looks at ``sys.modules`` (what actually loads), the
other reads every module's source with :mod:`ast`, so it also sees imports made inside functions, which load
only when called.
"""

import ast
import subprocess
import sys
from pathlib import Path

import latticeopt

CORE = ["latticeopt.design", "latticeopt.layout", "latticeopt.geometry", "latticeopt.mesh", "latticeopt.mesh.grid",
        "latticeopt.mesh.extruded", "latticeopt.mesh.tetwild", "latticeopt.mechanics", "latticeopt.electrics.forward",
        "latticeopt.electrics.jacobian", "latticeopt.coupled", "latticeopt.conductivity", "latticeopt.touches"]
ORCHESTRATION = ["study", "optimize", "cli", "recon", "learn", "gestures"]
#: Core modules and packages (every module below a package counts) for the source check.
CORE_SOURCES = ["design", "geometry", "mesh", "mechanics", "electrics", "coupled", "conductivity", "touches", "layout",
                "layout_dxf"]
#: Stages below the orchestration that used to borrow the study package's executor.
CONSUMERS = ["latticeopt.sensor_simulator", "latticeopt.sensor_model", "latticeopt.gestures", "latticeopt.recon",
             "latticeopt.render", "latticeopt.interop", "latticeopt.execution"]
ROOT = Path(latticeopt.__file__).parent


def test_core_modules_import_no_orchestration():
    code = ("import sys\n" + "".join(f"import {m}\n" for m in CORE) +
            "print(' '.join(sorted(m for m in sys.modules if m.split('.')[0] == 'latticeopt')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    leaked = [m for m in out if len(m.split(".")) > 1 and m.split(".")[1] in ORCHESTRATION]
    assert leaked == []


def _modules() -> dict[str, tuple[Path, bool]]:
    """Dotted name -> (file, is a package) for every module of the package."""
    out = {}
    for path in ROOT.rglob("*.py"):
        parts = list(path.relative_to(ROOT.parent).with_suffix("").parts)
        package = parts[-1] == "__init__"
        out[".".join(parts[:-1] if package else parts)] = (path, package)
    return out


def _targets(name: str, package: bool, node: ast.AST, modules) -> set[str]:
    """The package's modules an import statement of module ``name`` loads (relative imports resolved)."""
    if isinstance(node, ast.Import):
        wanted = [a.name for a in node.names]
    else:
        if node.level:
            base = name.split(".") if package else name.split(".")[:-1]
            base = base[:len(base) - (node.level - 1)]
            source = ".".join(base + ([node.module] if node.module else []))
        else:
            source = node.module or ""
        # `from . import plots` loads the module plots; `from .report import mean_se` loads report
        subs = [f"{source}.{a.name}" for a in node.names if f"{source}.{a.name}" in modules]
        wanted = subs or [source]
    out = set()
    for target in wanted:
        while target and target not in modules:  # `import latticeopt.mesh.grid.x` -> the deepest module there is
            target = target.rpartition(".")[0]
        if target.startswith("latticeopt") and target != name:
            out.add(target)
    return out


def import_graph() -> dict[str, set[str]]:
    """Module -> the package's modules it imports anywhere in its source (top level or inside functions)."""
    modules = _modules()
    graph = {}
    for name, (path, package) in modules.items():
        tree = ast.parse(path.read_text(), filename=str(path))
        graph[name] = set().union(*(_targets(name, package, node, modules) for node in ast.walk(tree)
                                    if isinstance(node, (ast.Import, ast.ImportFrom))))
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str]:
    """One import circle of ``graph`` as ``[a, b, ..., a]``, or ``[]``."""
    state: dict[str, int] = {}  # 1: on the current path, 2: finished

    def visit(node, path):
        state[node] = 1
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return path[path.index(nxt):] + [nxt]
            if nxt not in state and (found := visit(nxt, path + [nxt])):
                return found
        state[node] = 2
        return []

    for start in sorted(graph):
        if start not in state and (found := visit(start, [start])):
            return found
    return []


def _within(name: str, prefix: str) -> bool:
    return name == prefix or name.startswith(prefix + ".")


def test_the_cycle_finder_finds_a_circle_and_the_resolver_a_relative_import():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": set()}) == []
    graph = import_graph()
    assert "latticeopt.study.engine" in graph["latticeopt.study.sweep"]  # `from .engine import ...`
    assert "latticeopt.study.plots" in graph["latticeopt.study.report"]  # `from . import plots` inside a function
    assert "latticeopt.errors" in graph["latticeopt.study.engine"]  # `from ..errors import ...`


def test_no_import_circle_among_the_study_modules():
    study = {m: {t for t in deps if _within(t, "latticeopt.study")}
             for m, deps in import_graph().items() if _within(m, "latticeopt.study")}
    assert find_cycle(study) == []


def test_the_core_and_its_consumers_never_reach_study_or_optimize():
    graph = import_graph()
    starts = [m for m in graph if any(_within(m, f"latticeopt.{c}") for c in CORE_SOURCES)]
    starts += [m for m in graph if any(_within(m, c) for c in CONSUMERS)]
    assert len(starts) > 20
    for start in starts:
        seen, todo = {start}, [start]
        while todo:
            for nxt in graph[todo.pop()] - seen:
                seen.add(nxt)
                todo.append(nxt)
        upward = sorted(m for m in seen if _within(m, "latticeopt.study") or _within(m, "latticeopt.optimize"))
        assert upward == [], f"{start} reaches {upward}"
