"""The dependency rules, checked on every import statement of the tree (lazy imports inside functions included)."""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
NODE_PACKAGES = ("sim_bridge", "ssf_flow_node", "ssf_seg_node", "ssf_odom_node", "ssf_planner_node")
ABOVE_COMMON = NODE_PACKAGES + ("ssf_eval", "ssf_bringup")
CORE_LIBRARIES = {"numpy", "scipy", "torch", "sklearn", "open3d", "casadi", "pydantic", "small_gicp"}
CORE_COMMON = ("ssf_common.config", "ssf_common.errors", "ssf_common.geometry", "ssf_common.dataset", "ssf_common.records",
               "ssf_common.checkpoints", "ssf_common.training",  # training: the one step loop every trainer runs
               "ssf_common.temporal_prior",  # the prior M^(0) crosses from the fusion core to the flow node
               "ssf_common.vehicle")  # the sensor's mount and the vehicle's measured motion (flow and odometry)


def modules_of(package: str) -> list[Path]:
    return sorted((ROOT / package / package).rglob("*.py"))


def imports_of(path: Path) -> set[str]:
    """Every absolute module name a file imports."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module)
            names.update(f"{node.module}.{alias.name}" for alias in node.names)
    return names


def top(name: str) -> str:
    return name.split(".", 1)[0]


ALL_PACKAGES = ("ssf_common", "ssf_bringup", "ssf_eval") + NODE_PACKAGES
# Public names defined in more than one place on purpose: the command-line conventions. The list only shrinks: a name
# that became unique must leave it.
KNOWN_TWINS = {
    "main", "register", "add_parser",  # the entry-point conventions: each console script, each package's commands
}


def module_name(package: str, path: Path) -> str:
    parts = list(path.relative_to(ROOT / package).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def project_modules() -> dict[str, Path]:
    return {module_name(package, path): path for package in ALL_PACKAGES for path in modules_of(package)}


def is_cli(module: str) -> bool:
    last = module.rsplit(".", 1)[-1]
    return last in ("cli", "commands") or last.endswith("_cli")


def test_the_tree_has_the_packages_it_should():
    for package in ("ssf_common", "ssf_eval", "ssf_bringup") + NODE_PACKAGES:
        assert modules_of(package), package


@pytest.mark.parametrize("package", NODE_PACKAGES)
def test_no_node_package_imports_another(package):
    others = set(NODE_PACKAGES) - {package}
    for path in modules_of(package):
        crossing = sorted({name for name in imports_of(path) if top(name) in others | {"ssf_eval", "ssf_bringup"}})
        assert not crossing, f"{path.relative_to(ROOT)} imports {crossing}"


def test_ssf_common_names_no_package_above_it():
    for path in modules_of("ssf_common"):
        above = sorted({name for name in imports_of(path) if top(name) in ABOVE_COMMON})
        assert not above, f"{path.relative_to(ROOT)} imports {above}"
        text = path.read_text()
        named = [package for package in ABOVE_COMMON if f"'{package}." in text or f'"{package}.' in text]
        assert not named, f"{path.relative_to(ROOT)} names {named} in a string"


def test_no_module_is_named_like_a_folder_beside_its_package():
    """`python -m PKG.cli` from the workspace root sees PKG/launch/ (the launch files) as PKG.launch: a module of that
    name would not import there."""
    for package in ALL_PACKAGES:
        folders = {path.name for path in (ROOT / package).iterdir() if path.is_dir() and path.name != package}
        inside = {path.stem for path in (ROOT / package / package).iterdir() if path.suffix == ".py" or path.is_dir()}
        assert not folders & inside, f"{package}/{package} has modules named like the folders {sorted(folders & inside)}"


def test_only_the_application_imports_the_bringup_package():
    for package in ("ssf_common", "ssf_eval") + NODE_PACKAGES:
        for path in modules_of(package):
            bringup = sorted({name for name in imports_of(path) if top(name) == "ssf_bringup"})
            assert not bringup, f"{path.relative_to(ROOT)} imports {bringup}"


def test_the_common_library_holds_no_application():
    application = ("cli", "commands", "demo", "launch", "bench_graph", "bench_faults", "graphs")
    left = [name for name in application if any((ROOT / "ssf_common" / "ssf_common").glob(f"{name}*"))]
    assert not left, f"ssf_common holds {left}: the application lives in ssf_bringup"


def test_no_import_cycles_between_modules_lazy_imports_included():
    modules = project_modules()
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        imported = set()
        for target in imports_of(path):
            while target and target not in modules:
                target = target.rpartition(".")[0]
            if target and target != name and not name.startswith(target + "."):
                imported.add(target)
        graph[name] = imported
    cycles = [sorted(component) for component in strongly_connected(graph) if len(component) > 1]
    assert not cycles, f"modules that import each other: {cycles}"


def strongly_connected(graph: dict[str, set[str]]) -> list[set[str]]:
    """Tarjan's components of a directed graph (iteratively: the module graph is deep)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components: list[set[str]] = []
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, edges = work[-1]
            for child in edges:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph[child]))))
                    break
                if child in on_stack:
                    low[node] = min(low[node], index[child])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    component = set()
                    while True:
                        member = stack.pop()
                        on_stack.discard(member)
                        component.add(member)
                        if member == node:
                            break
                    components.append(component)
    return components


def test_the_cycle_finder_finds_a_cycle():
    components = strongly_connected({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}})
    assert sorted(sorted(component) for component in components if len(component) > 1) == [["a", "b", "c"]]


def test_command_line_modules_are_imported_only_by_their_own_packages_command_line():
    modules = project_modules()
    for name, path in modules.items():
        for target in imports_of(path):
            while target and target not in modules:
                target = target.rpartition(".")[0]
            if target and target != name and is_cli(target):
                assert is_cli(name) and top(name) == top(target), (
                    f"{path.relative_to(ROOT)} imports {target}: shared options and builders belong in a library module")


def test_public_classes_and_functions_have_one_name_each():
    where: dict[str, set[str]] = {}  # (typing.overload variants share their module)
    for package in ALL_PACKAGES:
        for path in modules_of(package):
            for node in ast.parse(path.read_text(), str(path)).body:
                if isinstance(node, (ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and not node.name.startswith("_"):
                    where.setdefault(node.name, set()).add(str(path.relative_to(ROOT)))
    twins = {name: paths for name, paths in where.items() if len(paths) > 1 and name not in KNOWN_TWINS}
    assert not twins, f"public names defined more than once: {twins}"
    settled = sorted(name for name in KNOWN_TWINS if len(where.get(name, set())) < 2)
    assert not settled, f"{settled} are unique now: take them off KNOWN_TWINS"


@pytest.mark.parametrize("package", NODE_PACKAGES[1:])
def test_cores_import_only_numerical_libraries_and_common_data(package):
    core = ROOT / package / package / "core"
    assert core.is_dir(), f"{package} has no core/"
    for path in sorted(core.rglob("*.py")):
        for name in imports_of(path):
            root = top(name)
            allowed = (root in sys.stdlib_module_names or root == "__future__" or root in CORE_LIBRARIES
                       or name.startswith(f"{package}.core") or name == f"{package}.core"
                       or any(name == prefix or name.startswith(prefix + ".") for prefix in CORE_COMMON))
            assert allowed, f"{path.relative_to(ROOT)} imports {name}"


def test_simulator_imports_no_perception():
    perception = {"ssf_flow_node", "ssf_seg_node", "ssf_odom_node", "ssf_planner_node", "ssf_eval"}
    for path in modules_of("sim_bridge"):
        assert not {top(name) for name in imports_of(path)} & perception, path


def test_ssf_help_lists_every_command(capsys):
    from ssf_bringup.cli import main

    with pytest.raises(SystemExit) as exit_code:
        main(["--help"])
    assert exit_code.value.code == 0
    text = capsys.readouterr().out
    for command in ("demo", "launch", "record", "bag", "sim", "dataset", "flow", "seg", "train", "eval", "bench"):
        assert f"    {command}" in text, command
    for group, commands in (("eval", ("flow", "seg", "fusion")), ("bench", ("transport", "sim", "flow", "seg", "fusion")),
                            ("train", ("flow",))):
        with pytest.raises(SystemExit):
            main([group, "--help"])
        listing = capsys.readouterr().out
        for command in commands:
            assert f"    {command}" in listing, f"{group} {command}"


@pytest.mark.parametrize("module, name", [
    ("ssf_flow_node.node", "FlowNode"), ("ssf_seg_node.node", "SegNode"), ("ssf_seg_node.fusion_node", "FusionNode"),
    ("ssf_odom_node.node", "OdomNode"), ("ssf_planner_node.node", "PlannerNode"), ("sim_bridge.node", "SimBridgeNode"),
])
def test_no_node_shadows_the_middleware_nodes_own_machinery(module, name):
    """A node's private helper named like one of the middleware Node's (a planner `_on_clock` once swallowed /clock
    under simulated time) breaks the node silently; only the documented hooks may be overridden."""
    import importlib

    from ssf_common.middleware import Node

    node_class = getattr(importlib.import_module(module), name)
    hooks = {"on_shutdown"}
    machinery = {attribute for attribute in vars(Node) if attribute.startswith("_") and not attribute.startswith("__")}
    shadowed = {attribute for klass in node_class.__mro__[:node_class.__mro__.index(Node)] for attribute in vars(klass)
                if attribute in machinery} - hooks
    assert not shadowed, f"{name} redefines {sorted(shadowed)} of the middleware Node"
