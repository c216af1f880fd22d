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
               "ssf_common.checkpoints", "ssf_common.interrupts",  # interrupts: a training loop stops cleanly
               "ssf_common.temporal_prior")  # the prior M^(0) crosses from the fusion core to the flow node


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


def test_only_the_application_imports_the_bringup_package():
    for package in ("ssf_common", "ssf_eval") + NODE_PACKAGES:
        for path in modules_of(package):
            bringup = sorted({name for name in imports_of(path) if top(name) == "ssf_bringup"})
            assert not bringup, f"{path.relative_to(ROOT)} imports {bringup}"


def test_the_common_library_holds_no_application():
    application = ("cli", "commands", "demo", "launch", "bench_graph", "bench_faults", "graphs")
    left = [name for name in application if any((ROOT / "ssf_common" / "ssf_common").glob(f"{name}*"))]
    assert not left, f"ssf_common holds {left}: the application lives in ssf_bringup"


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
