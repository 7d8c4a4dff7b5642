"""A build on a real two-node Ray cluster started with the ``ray`` CLI, one node killed mid-build.

The head and a second node run as separate Ray nodes of one CPU each (``ray start --head``,
``ray start --address``), in their own temporary folder, on free ports, with their own
authentication token. The build runs units on both, loses the second node (every one of its
processes killed outright) while it writes a unit, reruns that unit on the head, and ends with
the bytes of the local executor. The cluster is torn down whatever happens.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from .conftest import UNIT_IDS, BuiltDataset, reproducible_files

START_TIMEOUT_S = 90
_STAGING = re.compile(r"^\.(?P<unit>.+)\.(?P<pid>[0-9]+)-[0-9a-f]{12}\.tmp$")  # files.temp_path


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def _stat(pid: int) -> list[str] | None:
    """/proc/<pid>/stat fields after the command name (state, ppid, pgrp, ...); None when gone."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None


def _processes() -> list[int]:
    return [int(p.name) for p in Path("/proc").iterdir() if p.name.isdigit()]


@dataclass(frozen=True)
class RayNode:
    group: int  # the process group of its `ray start` (its daemons stay in it)
    raylet: int  # the raylet's pid: Ray's worker processes are its children (in sessions of their own)
    node_id: str

    def processes(self) -> list[int]:
        found = []
        for pid in _processes():
            fields = _stat(pid)
            if fields and fields[0] != "Z" and (int(fields[2]) == self.group or int(fields[1]) == self.raylet):
                found.append(pid)
        return found

    def runs(self, pid: int) -> bool:
        fields = _stat(pid)
        return fields is not None and int(fields[1]) == self.raylet

    def kill(self) -> list[int]:
        """SIGKILL every process of the node at once, as when its machine is lost."""
        victims = self.processes()
        for pid in victims:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        return victims


@dataclass(frozen=True)
class LocalCluster:
    temp: Path
    address: str
    environment: dict[str, str]  # what a driver (and every node) needs: the token
    head: RayNode
    worker: RayNode


def _ray_command() -> str:
    beside = Path(sys.executable).with_name("ray")
    return str(beside) if beside.is_file() else (shutil.which("ray") or "ray")


def _start_node(args: list[str], environment: dict[str, str], temp: Path, nodes: list[RayNode]) -> RayNode:
    ports = ["--node-manager-port", "--object-manager-port", "--dashboard-agent-listen-port",
             "--dashboard-agent-grpc-port", "--runtime-env-agent-port", "--metrics-export-port"]
    command = [_ray_command(), "start", *args, "--num-cpus", "1", "--node-ip-address", "127.0.0.1",
               "--disable-usage-stats", *(x for name in ports for x in (name, str(_free_port())))]
    process = subprocess.Popen(command, start_new_session=True, env=environment, stdout=subprocess.PIPE,
                               stderr=subprocess.STDOUT, text=True)
    try:
        output, _ = process.communicate(timeout=START_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
        output, _ = process.communicate()
    group = process.pid  # its own session: the daemons it leaves running keep this group
    raylets = [pid for pid in _processes() if (_stat(pid) or ["", "", "0"])[2] == str(group)
               and b"raylet/raylet" in Path(f"/proc/{pid}/cmdline").read_bytes()]
    node = RayNode(group=group, raylet=raylets[0] if raylets else -1, node_id="")
    if process.returncode != 0 or not raylets:
        nodes.append(node)  # whatever it started is stopped with the rest
        last = [line for line in output.splitlines() if line.strip()][-3:]
        pytest.skip(f"Ray cannot start a node here (`ray start` exit {process.returncode}): {' | '.join(last)}")
    arguments = Path(f"/proc/{raylets[0]}/cmdline").read_bytes().split(b"\0")
    node_id = next(a.split(b"=", 1)[1].decode() for a in arguments if a.startswith(b"--node_id="))
    node = RayNode(group=group, raylet=raylets[0], node_id=node_id)
    nodes.append(node)
    return node


def _stop(nodes: list[RayNode], temp: Path) -> None:
    """Kill what this cluster started, and only that: its nodes' processes, then any process left
    whose command line names its temporary folder."""
    for node in nodes:
        node.kill()
    marker = str(temp).encode()
    for pid in _processes():
        try:
            if marker in Path(f"/proc/{pid}/cmdline").read_bytes():
                os.kill(pid, signal.SIGKILL)
        except (OSError, ProcessLookupError):
            continue


@pytest.fixture
def ray_cluster(session_env: Path) -> Iterator[LocalCluster]:
    """A head and a second node, one CPU each, as `ray start` makes them; torn down at the end."""
    pytest.importorskip("ray")
    temp = Path(tempfile.mkdtemp(prefix="bimscan-ray-", dir="/tmp"))  # short: Ray's socket paths live under it
    token = temp / "auth_token"
    token.write_text(secrets.token_hex(32))
    environment = {"RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN_PATH": str(token), "RAY_USAGE_STATS_ENABLED": "0"}
    node_environment = os.environ | environment
    nodes: list[RayNode] = []
    try:
        port = _free_port()
        head = _start_node(["--head", "--port", str(port), "--temp-dir", str(temp), "--include-dashboard", "false",
                            "--dashboard-port", str(_free_port())], node_environment, temp, nodes)
        worker = _start_node(["--address", f"127.0.0.1:{port}"], node_environment, temp, nodes)
        yield LocalCluster(temp=temp, address=f"127.0.0.1:{port}", environment=environment, head=head, worker=worker)
    finally:
        _stop(nodes, temp)
        shutil.rmtree(temp, ignore_errors=True)


def _built_on(out: Path) -> dict[str, str]:
    """unit -> the Ray node its timings say built it."""
    return {path.parent.name: json.loads(path.read_text())["ray_node"] for path in out.glob("units/*/timings.json")}


def _build_on_cluster(cluster: LocalCluster, spec: Path, out: Path, *,
                      kill_when_writing: RayNode | None = None) -> tuple[str, tuple[str, list[int]] | None]:
    """`bimscan build SPEC OUT --executor ray --ray-address ...` as a user runs it; with
    ``kill_when_writing``, that node is killed (every process at once) as soon as it writes a unit.
    Returns what the build printed and (the unit it was writing, the processes killed)."""
    command = [sys.executable, "-m", "bimscan.cli.main", "build", str(spec), str(out),
               "--executor", "ray", "--ray-address", cluster.address]
    build = subprocess.Popen(command, env=os.environ | cluster.environment, stdout=subprocess.PIPE,
                             stderr=subprocess.STDOUT, text=True, start_new_session=True)
    killed = None
    try:
        deadline = time.monotonic() + 240
        while kill_when_writing is not None and killed is None and build.poll() is None and time.monotonic() < deadline:
            names = os.listdir(out / "units") if (out / "units").is_dir() else []
            writing = [(name, m["unit"], int(m["pid"])) for name, m in zip(names, map(_STAGING.match, names))
                       if m and kill_when_writing.runs(int(m["pid"]))]
            for staging, unit, pid in writing[:1]:
                # Freeze the writer at once (one signal: listing the node's processes to kill them takes
                # long enough on a loaded machine for a small unit to finish), then kill the node only
                # if the unit is still unfinished; a unit finished in between is not a lost unit.
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGSTOP)
                if (out / "units" / staging).exists():
                    killed = (unit, kill_when_writing.kill())
                else:
                    with contextlib.suppress(ProcessLookupError):
                        os.kill(pid, signal.SIGCONT)
            time.sleep(0.005)
        output, _ = build.communicate(timeout=240)
    finally:
        if build.poll() is None:
            os.killpg(build.pid, signal.SIGKILL)
            build.wait()
    assert build.returncode == 0, output
    return output, killed


@pytest.mark.slow
def test_a_build_on_a_two_node_ray_cluster_runs_on_both_loses_a_node_mid_unit_and_writes_the_local_executors_bytes(
        ray_cluster: LocalCluster, reference_dataset: BuiltDataset, tmp_path: Path) -> None:
    from bimscan.cli.main import main

    out = tmp_path / "cluster"
    output, _ = _build_on_cluster(ray_cluster, reference_dataset.spec, out)
    nodes = _built_on(out)
    assert sorted(nodes) == sorted(UNIT_IDS)
    assert set(nodes.values()) == {ray_cluster.head.node_id, ray_cluster.worker.node_id}, output  # units ran on both
    assert "units built per node:" in output
    assert reproducible_files(out) == reproducible_files(reference_dataset.out)

    # Two units to build again, one per node: the second node dies while it writes its unit.
    for unit in ("north__dense", "south__dense"):
        shutil.rmtree(out / "units" / unit)
    output, killed = _build_on_cluster(ray_cluster, reference_dataset.spec, out, kill_when_writing=ray_cluster.worker)
    assert killed is not None, f"the second node wrote no unit; the build said:\n{output}"
    lost_unit, victims = killed
    assert ray_cluster.worker.raylet in victims and not ray_cluster.worker.processes()  # the node is gone
    assert "2 built, 2 already done, 0 failed" in output
    manifest = json.loads((out / "manifest.json").read_text())
    assert [(u["id"], u["status"]) for u in manifest["units"]] == [(unit, "done") for unit in UNIT_IDS]
    assert _built_on(out)[lost_unit] == ray_cluster.head.node_id  # the lost unit was built again on the head
    # no staging folder left by the killed task; the same bytes as the local executor; checksums verify
    assert reproducible_files(out) == reproducible_files(reference_dataset.out)
    assert main(["stats", str(out), "--verify", "--out", str(tmp_path / "stats")]) == 0
