"""The package's layers: no import cycle among panda_lead's modules, and the configuration,
the rollout format and the statistics sit below the simulation (they import without MuJoCo),
so a reader of results, or a script that only checks its command line, never loads it."""

import ast
import subprocess
import sys
from pathlib import Path

import panda_lead

PACKAGE = Path(panda_lead.__file__).parent
# Modules below the simulation: none of them may import these, even lazily.
BELOW_SIMULATION = ("config", "ikconfig", "rollout", "metrics", "trajectory", "seeds", "errors",
                    "atomicio", "paths")
SIMULATION = ("core", "core_one", "task", "task_one", "env", "vector", "sb3_vecenv",
              "clearance")


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path, top_level_only: bool) -> set[str]:
    """The modules a file imports (absolute names; panda_lead's and third parties')."""
    name = _module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    tree = ast.parse(path.read_text(), str(path))
    nodes = tree.body if top_level_only else ast.walk(tree)
    found = set()
    for node in nodes:
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")
                up = up[:len(up) - node.level + 1]
                base = ".".join(up + ([node.module] if node.module else []))
            found.add(base)
            found |= {f"{base}.{a.name}" for a in node.names}  # `from . import x`: module x
    return found


def _graph(top_level_only: bool) -> dict[str, set[str]]:
    """panda_lead's import graph: module -> the panda_lead modules it imports."""
    files = {_module_name(p): p for p in PACKAGE.rglob("*.py")}
    return {name: {m for m in _imports(path, top_level_only) if m in files and m != name}
            for name, path in files.items()}


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import cycle of the graph (a list of modules), or None."""
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    path: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        path.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                return path[path.index(nxt):] + [nxt]
            if nxt not in state and (found := visit(nxt)):
                return found
        path.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state and (found := visit(node)):
            return found
    return None


def test_no_import_cycle_among_the_modules():
    """Counting the imports a module makes on import (a cycle there breaks an import); the
    lazy ones inside functions may point back up, by design (a runner imports the task)."""
    graph = _graph(top_level_only=True)
    assert "panda_lead.core" in graph and "panda_lead.core" in graph["panda_lead.task"]
    assert _cycle(graph) is None, " -> ".join(_cycle(graph))


def test_the_cycle_check_finds_a_cycle():
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": set()}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": set()}) is None


def test_configuration_and_formats_do_not_import_the_simulation():
    """config, rollout, metrics, trajectory, ... import neither MuJoCo nor a module built on
    it, not even lazily; except rollout, which plays episodes (iter_record) and so imports
    the task inside that function, never on import."""
    files = {_module_name(p): p for p in PACKAGE.rglob("*.py")}
    checked = 0
    for name, path in files.items():
        layer = name.removeprefix("panda_lead.").split(".")[0]
        if layer not in BELOW_SIMULATION:
            continue
        imported = _imports(path, top_level_only=layer == "rollout")
        bad = {m for m in imported if m.split(".")[0] == "mujoco"
               or (m.startswith("panda_lead.") and m.split(".")[1] in SIMULATION)}
        assert not bad, f"{name} imports {sorted(bad)}"
        checked += 1
    assert checked >= len(BELOW_SIMULATION) + 2  # (metrics is a package of several)


def test_importing_the_statistics_loads_no_mujoco():
    """In a fresh process (sys.modules is per process): the statistics, the rollout format and
    the configuration import without MuJoCo; the env, by contrast, loads it."""
    code = ("import sys, panda_lead.metrics, panda_lead.rollout, panda_lead.config\n"
            "assert 'mujoco' not in sys.modules, sorted(m for m in sys.modules "
            "if m.startswith('panda_lead'))\n"
            "import panda_lead.env\n"
            "assert 'mujoco' in sys.modules\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
