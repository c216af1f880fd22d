"""`ssf launch`: start a graph of node processes from YAML, prefix their output, restart crashes, stop cleanly."""

from __future__ import annotations

import ctypes
import functools
import math
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pydantic import Field

from ssf_common import config as config_lib
from ssf_common.checks import require_finite
from ssf_common.config import Section, param_text
from ssf_common.errors import ConfigError
from ssf_common.middleware.params import params_file_sections
from ssf_common.viewer.command import VIEWER_NODE

if TYPE_CHECKING:
    from ssf_common.viewer.server import ViewerConfig

_PR_SET_PDEATHSIG = 1
CONFIG_ERROR_EXIT = 2  # a node's answer to bad parameters or files: restarting cannot help
_STOPPED_CODES = (0, 130, -signal.SIGINT)  # how a process ends when it was asked to stop
# The child imports its entry point with SIGINT blocked (see _start_child): an interrupt inside a C
# extension's import surfaces as an ImportError, not a KeyboardInterrupt. A Ctrl-C that arrived meanwhile
# is delivered when the imports are done and ends the child quietly with 130.
_BOOTSTRAP = (
    "import signal, sys\n"
    "try:\n"
    "    from {module} import {func}\n"
    "    signal.pthread_sigmask(signal.SIG_UNBLOCK, {{signal.SIGINT}})\n"
    "    code = {func}()\n"
    "except KeyboardInterrupt:\n"
    "    code = 130\n"
    "sys.exit(code)\n"
)


class NodeSpec(Section):
    """One node process of a graph."""

    executable: str
    name: str | None = None
    parameters: dict[str, Any] = Field(default_factory=dict)
    params_file: str | None = None
    remappings: dict[str, str] = Field(default_factory=dict)
    arguments: list[str] = Field(default_factory=list)
    respawn: bool = True
    max_restarts: int = Field(default=3, ge=0)
    required: bool = False  # when it exits for good, the whole graph stops
    environment: dict[str, str] = Field(default_factory=dict)
    ros_args: bool = True  # node executables take --ros-args; tools such as `ssf record` do not
    nice: int = Field(default=0, ge=0, le=19, description="scheduling niceness: a node off the critical path (one whose "
                      "answer no command waits for) yields the cores to those on it while both want them")


class GraphSpec(Section):
    """A graph: node processes plus parameters every node gets."""

    nodes: list[NodeSpec] = Field(min_length=1)
    global_parameters: dict[str, Any] = Field(default_factory=dict)
    stop_timeout_s: float = Field(default=5.0, gt=0)
    drain_s: float = Field(default=1.0, ge=0, le=60, description="after a required node's clean end, the others run "
                           "this long to take in its last messages (a recorder its last scan) before they are stopped")


def load_graph(path: str | Path, overrides: dict[str, Any] | None = None) -> GraphSpec:
    """Read and validate a graph file; relative params files resolve against its folder."""
    path = Path(path)
    graph = config_lib.build(GraphSpec, config_lib.read_yaml(path), source=str(path))
    nodes = []
    for node in graph.nodes:
        params_file = node.params_file
        if params_file and not Path(params_file).is_absolute():
            params_file = str((path.parent / params_file).resolve())
        if params_file:
            params_file_sections(Path(params_file))  # a broken params file is the graph's error, before any start
        nodes.append(node.model_copy(update={"params_file": params_file}))
    graph = graph.model_copy(update={"nodes": nodes})
    if overrides:
        graph = graph.model_copy(update={"global_parameters": {**graph.global_parameters, **overrides}})
    for index, node in enumerate(graph.nodes):
        node_parameters(node, graph.global_parameters, f"{path}: nodes[{index}] ({node.name or node.executable})")
    return graph


def node_parameters(node: NodeSpec, global_parameters: dict[str, Any], source: str = "graph") -> dict[str, Any]:
    """The parameters one node gets, as the dotted names nodes declare: nested mappings flattened, its own
    over the global ones; ConfigError (naming `source` and the parameter) for a value no -p can carry."""
    merged = {**config_lib.flatten(global_parameters), **config_lib.flatten(node.parameters)}
    for name, value in merged.items():
        _check_parameter(name, value, source)
    return merged


def _check_parameter(name: str, value: Any, source: str) -> None:
    items = value if isinstance(value, (list, tuple)) else [value]
    for item in items:
        if isinstance(item, (dict, list, tuple)) or not isinstance(item, (bool, int, float, str)):
            raise ConfigError(f"{source}: parameter '{name}': {item!r} is not a parameter value "
                              "(a number, bool, string, or a list of them)")
        if isinstance(item, float) and not math.isfinite(item):
            raise ConfigError(f"{source}: parameter '{name}' must be a finite number, got {item!r}")
    back_name, back = config_lib.parse_override(f"{name}:={param_text(value)}", f"{source}: parameter")
    if back_name != name or back != (list(value) if isinstance(value, tuple) else value):
        raise ConfigError(f"{source}: parameter '{name}': {value!r} cannot be passed as -p {name}:=...")


def _console_script(executable: str) -> tuple[str, str]:
    """Module and function of an installed console script."""
    for entry in metadata.entry_points(group="console_scripts"):
        if entry.name == executable:
            module, _, func = entry.value.partition(":")
            return module, func or "main"
    raise ConfigError(f"no executable named '{executable}' is installed (pip install the repository)")


def command_line(node: NodeSpec, global_parameters: dict[str, Any]) -> list[str]:
    """The argv that starts one node process, in ros2 run form."""
    module, func = _console_script(node.executable.split("/")[-1])
    argv = [sys.executable, "-P", "-c", _BOOTSTRAP.format(module=module, func=func)]
    argv += list(node.arguments)
    if not node.ros_args:
        return argv
    ros_args: list[str] = []
    if node.name:
        ros_args += ["-r", f"__node:={node.name}"]
    for source, target in node.remappings.items():
        ros_args += ["-r", f"{source}:={target}"]
    if node.params_file:
        ros_args += ["--params-file", node.params_file]
    for name, value in node_parameters(node, global_parameters, node.name or node.executable).items():
        ros_args += ["-p", f"{name}:={param_text(value)}"]
    return argv + (["--ros-args", *ros_args] if ros_args else [])


def _start_child(nice: int = 0) -> None:
    """In the child, before exec: SIGTERM if the launcher dies (no orphans); SIGINT held until the bootstrap; its
    niceness."""
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    if nice:
        os.nice(nice)
    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
    except OSError:
        pass


@dataclass
class ManagedProcess:
    """A node process and its restart bookkeeping."""

    spec: NodeSpec
    label: str
    argv: list[str]
    process: subprocess.Popen | None = None
    restarts: int = 0
    finished: bool = False
    exit_codes: list[int] = field(default_factory=list)
    failure: str | None = None  # why it ended for good, when that was not a clean end


class Launcher:
    """Runs a graph until interrupted or a required node ends; never leaves orphans; says what failed."""

    def __init__(self, graph: GraphSpec, *, output: Any = None) -> None:
        self.graph = graph
        self.output = output or sys.stdout
        self._stopping = threading.Event()
        self._print_lock = threading.Lock()
        self.crashes: list[tuple[str, int]] = []  # (label, exit code) of every unplanned end, restarted or not
        self.managed = [
            ManagedProcess(node, node.name or node.executable, command_line(node, graph.global_parameters))
            for node in graph.nodes
        ]

    @property
    def failures(self) -> list[tuple[str, str]]:
        """(label, what happened) for each node that ended for good without a clean end."""
        return [(managed.label, managed.failure) for managed in self.managed if managed.failure]

    def start(self) -> None:
        """Start every node process."""
        for managed in self.managed:
            self._spawn(managed)

    def _spawn(self, managed: ManagedProcess) -> None:
        # One BLAS/OpenMP thread per node unless the user says otherwise: several nodes share the cores.
        env = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", **os.environ, **managed.spec.environment, "PYTHONUNBUFFERED": "1"}
        managed.process = subprocess.Popen(
            managed.argv,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            env=env,
            preexec_fn=functools.partial(_start_child, managed.spec.nice),
            process_group=0,  # a Ctrl-C in the terminal reaches the launcher only; it stops the nodes in order
        )
        self._say(managed.label, f"started (pid {managed.process.pid})")
        threading.Thread(target=self._pump, args=(managed, managed.process), daemon=True).start()

    def _pump(self, managed: ManagedProcess, process: subprocess.Popen) -> None:
        assert process.stdout is not None
        for raw in process.stdout:
            self._say(managed.label, raw.decode(errors="replace").rstrip("\n"))

    def _say(self, label: str, text: str) -> None:
        with self._print_lock:
            print(f"[{label}] {text}", file=self.output, flush=True)

    def say(self, label: str, text: str) -> None:
        """Print one line under a label, whole among the nodes' lines."""
        self._say(label, text)

    def kill(self, label: str) -> int:
        """SIGKILL one node's process (a fault campaign's crash); the next poll() sees it and restarts it as any
        crash. Returns its pid."""
        managed = next((managed for managed in self.managed if managed.label == label), None)
        if managed is None or managed.process is None or managed.process.poll() is not None:
            raise ConfigError(f"no running node named '{label}' in the graph")
        managed.process.kill()
        managed.process.wait()
        return managed.process.pid

    def poll(self) -> bool:
        """Restart crashed nodes; return False when the graph should stop."""
        for managed in self.managed:
            process = managed.process
            if managed.finished or process is None or process.poll() is None:
                continue
            code = process.returncode
            managed.exit_codes.append(code)
            if self._stopping.is_set():
                self._finish_stopped(managed, code)
                continue
            if code != 0:
                self.crashes.append((managed.label, code))
            if code == CONFIG_ERROR_EXIT:
                managed.finished = True
                managed.failure = f"exited with code {code} (a configuration error)"
                self._say(managed.label, f"{managed.failure}; not restarted")
            elif code != 0 and managed.spec.respawn and managed.restarts < managed.spec.max_restarts:
                managed.restarts += 1
                self._say(managed.label, f"exited with code {code}; restart {managed.restarts}/{managed.spec.max_restarts}")
                if self._stopping.wait(min(0.5 * managed.restarts, 2.0)):
                    managed.finished = True
                    continue
                self._spawn(managed)
                continue
            else:
                managed.finished = True
                managed.failure = None if code == 0 else f"exited with code {code}"
                self._say(managed.label, "finished" if code == 0 else f"{managed.failure}; not restarted")
            if managed.spec.required:
                return False
        return not all(managed.finished for managed in self.managed)

    def _ended_cleanly(self) -> bool:
        """Whether the graph ends because a required node finished its job (not a failure)."""
        return not self.failures and any(m.finished and m.spec.required for m in self.managed)

    def _finish_stopped(self, managed: ManagedProcess, code: int) -> None:
        managed.finished = True
        if code == -signal.SIGKILL:
            managed.failure = f"did not stop within {self.graph.stop_timeout_s:g} s and was killed"
        elif code not in _STOPPED_CODES and code != -signal.SIGTERM:
            managed.failure = f"exited with code {code} while stopping"

    def stop(self) -> None:
        """SIGINT every node, then SIGTERM, then SIGKILL after the timeout; wait for all."""
        self._stopping.set()
        live = [m.process for m in self.managed if m.process is not None and m.process.poll() is None]
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
            for process in live:
                if process.poll() is None:
                    process.send_signal(sig)
            deadline = time.monotonic() + self.graph.stop_timeout_s
            while time.monotonic() < deadline and any(p.poll() is None for p in live):
                time.sleep(0.05)
            live = [p for p in live if p.poll() is None]
            if not live:
                break
        for managed in self.managed:
            if managed.process is not None:
                code = managed.process.wait()
                if not managed.finished:
                    managed.exit_codes.append(code)
                    self._finish_stopped(managed, code)

    def run(self, duration_s: float | None = None) -> int:
        """Start, supervise until Ctrl-C/SIGTERM, a required node's end or the duration; then stop all.

        Returns 0 when every node ended cleanly, 1 when one failed (say which, one line each)."""
        if duration_s is not None:
            duration_s = require_finite(duration_s, "--duration", above=0.0)
        stop_requested = threading.Event()

        def on_signal(_signum: int, _frame: object) -> None:
            stop_requested.set()

        previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
        deadline = None if duration_s is None else time.monotonic() + duration_s
        try:
            self.start()
            while not stop_requested.is_set():
                if not self.poll():
                    if self._ended_cleanly():
                        stop_requested.wait(self.graph.drain_s)
                    break
                if deadline is not None and time.monotonic() >= deadline:
                    break
                stop_requested.wait(0.1)
        finally:
            self.stop()
            for sig, handler in previous.items():
                signal.signal(sig, handler)
        for label, failure in self.failures:
            self._say("launch", f"{label} {failure}")
        return 1 if self.failures else 0


def with_viewer(graph: GraphSpec, config: ViewerConfig | None) -> GraphSpec:
    """The graph plus an `ssf view` process (unchanged without a config); the port is checked free first."""
    if config is None:
        return graph
    from ssf_common.viewer.server import check_port_free

    if config.port:
        check_port_free(config.host, config.port)
    viewer = NodeSpec(executable="ssf", name=VIEWER_NODE, ros_args=False, respawn=False,
                      arguments=["view", "--port", str(config.port), "--host", config.host])
    return graph.model_copy(update={"nodes": [*graph.nodes, viewer]})
