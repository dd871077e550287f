"""The code's shape: layers, no import circles, constant models, functions of a readable size."""
import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("rigid", "fem", "hybrid")
MAX_FUNCTION_LINES = 80
MAX_MODULE_LINES = 420


def modules():
    """{dotted name: parsed module} of every module of the three packages."""
    out = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            out[name] = (path, ast.parse(path.read_text()))
    return out


def imports(name, tree, known):
    """The modules of ``known`` that module ``name`` imports when it is loaded (top level)."""
    package = name if name in known and known[name][0].name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in tree.body:
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(up + ([base] if base else []))
            found.add(base)
            found |= {f"{base}.{a.name}" for a in node.names}
    return {m for m in found if m in known and m != name}


def test_rigid_and_fem_do_not_import_hybrid_and_fem_does_not_import_the_app():
    for name, (path, tree) in modules().items():
        for node in ast.walk(tree):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                targets = [a.name for a in node.names] if isinstance(node, ast.Import) else [node.module or ""]
                top = {t.split(".")[0] for t in targets}
                if name.startswith(("rigid", "fem")):
                    assert "hybrid" not in top, f"{path} imports hybrid"
                if name.startswith("rigid"):
                    assert "fem" not in top, f"{path} imports fem"
                if name.startswith("hybrid.coupling"):
                    assert not any(t.startswith("hybrid.app") for t in targets) and getattr(node, "level", 0) < 2, \
                        f"{path}: the coupling imports the application"


def test_no_import_circles():
    known = modules()
    graph = {name: imports(name, tree, known) for name, (_, tree) in known.items()}
    state = {}

    def visit(node, path):
        state[node] = "open"
        for nxt in sorted(graph[node]):
            if state.get(nxt) == "open":
                raise AssertionError("import circle: " + " -> ".join(path[path.index(nxt):] + [nxt]))
            if nxt not in state:
                visit(nxt, path + [nxt])
        state[node] = "done"

    for name in sorted(graph):
        if name not in state:
            visit(name, [name])


def test_models_are_never_changed_in_place_and_modules_hold_no_mutable_state():
    for name, (path, tree) in modules().items():
        assert "object.__setattr__" not in path.read_text(), f"{path} sets attributes of a frozen object"
        for node in tree.body:
            if isinstance(node, ast.Global):
                raise AssertionError(f"{path}: global statement")
            for inner in ast.walk(node) if isinstance(node, (ast.FunctionDef, ast.ClassDef)) else ():
                assert not isinstance(inner, ast.Global), f"{path}:{inner.lineno}: global statement"
            if isinstance(node, (ast.Assign, ast.AnnAssign)) and isinstance(node.value, (ast.List, ast.Dict, ast.Set)):
                targets = node.targets if isinstance(node, ast.Assign) else [node.target]
                names = [t.id for t in targets if isinstance(t, ast.Name)]
                assert all(n.isupper() or n == "__all__" for n in names), \
                    f"{path}:{node.lineno}: module-level mutable {names}"


def test_functions_and_modules_fit_in_one_reading():
    long = []
    for name, (path, tree) in modules().items():
        lines = len(path.read_text().splitlines())
        if lines > MAX_MODULE_LINES:
            long.append(f"{path.relative_to(ROOT)}: {lines} lines")
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                size = node.end_lineno - node.lineno + 1
                if size > MAX_FUNCTION_LINES:
                    long.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.name}: {size} lines")
    assert not long, "\n".join(long)
