"""The package built, tested and run as a ROS 2 user does (CI's ROS leg; skipped only where colcon or rclpy
cannot be imported): a colcon workspace with a copy of this repository under ``src/``, ``colcon build`` with
and without ``--symlink-install``, ``colcon test`` (pytest on a part of the suite, its result read back by
``colcon test-result``), the installed layout (``lib/tensegrity_sim/sim_node`` where ``ros2 run`` looks, the
ament resource index, ``share/tensegrity_sim`` with package.xml, the launch file, the config and msg_docs),
and the installed ``sim_node``, found through the ament index from the workspace's ``setup.sh`` as ``ros2
run`` finds it, publishing its poses to an rclpy peer in this process.

colcon, colcon-ros and colcon-python-setup-py come from PyPI (setup.py's ``colcon`` extra), rclpy from the
Jazzy wheels (the ``ros`` extra); the domain and the discovery range are the test process's (conftest.py).
"""
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytest.importorskip("colcon_core")
pytest.importorskip("colcon_ros")
rclpy = pytest.importorskip("rclpy")

from geometry_msgs.msg import PoseArray  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402

from dds_child import NODE_OUTPUTS  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
COLCON = Path(sys.executable).with_name("colcon")   # installed beside this interpreter (the colcon extra)
PACKAGE = "tensegrity_sim"
# the repository's own outputs and caches, not part of a source checkout (numba's cached kernels do come:
# copied with their sources' times they stay valid, so the node starts without compiling them again)
LEAVE_OUT = shutil.ignore_patterns(".git", "build", "install", "log", "bags", "plots", ".pytest_cache",
                                   ".hypothesis", "*.egg-info", "site", "*.pyc")


def colcon(workspace: Path, *args: str, timeout: float = 300) -> str:
    out = subprocess.run([str(COLCON), *args], cwd=workspace, capture_output=True, text=True, timeout=timeout,
                         env=dict(os.environ, COLCON_HOME=str(workspace / ".colcon")))
    assert out.returncode == 0, f"colcon {' '.join(args)} failed:\n{out.stdout[-4000:]}\n{out.stderr[-4000:]}"
    return out.stdout


def sourced(workspace: Path, command: str, timeout: float = 60) -> str:
    """``command``'s output in a shell that sourced the workspace's ``install/setup.sh``."""
    out = subprocess.run(["sh", "-c", f". ./install/setup.sh && {command}"], cwd=workspace, capture_output=True,
                         text=True, timeout=timeout)
    assert out.returncode == 0, out.stderr[-4000:]
    return out.stdout.strip()


def built(tmp_path_factory, kind: str) -> Path:
    """A workspace with a copy of the repository in src/, built (``--symlink-install`` or a plain install)."""
    ws = tmp_path_factory.mktemp(f"colcon_{kind}")
    shutil.copytree(ROOT, ws / "src" / PACKAGE, ignore=LEAVE_OUT, symlinks=True)
    colcon(ws, "build", *(["--symlink-install"] if kind == "symlink" else []))
    return ws


@pytest.fixture(scope="module")
def symlinked(tmp_path_factory):
    return built(tmp_path_factory, "symlink")


@pytest.fixture(scope="module")
def plain(tmp_path_factory):
    return built(tmp_path_factory, "plain")


@pytest.mark.parametrize("kind", ["symlink", "plain"])
def test_installed_layout(kind, request):
    ws = request.getfixturevalue({"symlink": "symlinked", "plain": "plain"}[kind])
    prefix = ws / "install" / PACKAGE
    src = ws / "src" / PACKAGE
    assert (prefix / "share" / "ament_index" / "resource_index" / "packages" / PACKAGE).is_file()
    share = prefix / "share" / PACKAGE
    assert (share / "package.xml").read_text() == (src / "package.xml").read_text()
    for folder, pattern in (("launch", "*.launch.py"), ("config", "*.yaml"), ("msg_docs", "*.md")):
        installed = sorted(p.name for p in (share / folder).iterdir())
        assert installed == sorted(p.name for p in (src / folder).glob(pattern)) and installed, folder
    for script in ("sim_node", "tensegrity-sim"):
        path = prefix / "lib" / PACKAGE / script
        assert path.is_file() and os.access(path, os.X_OK), script
    # the workspace's environment finds the package where ros2 run looks, and imports the workspace's copy
    found = sourced(ws, f"{sys.executable} -c \"from ament_index_python.packages import get_package_prefix as p; "
                        f"print(p('{PACKAGE}'))\"")
    assert Path(found) == prefix
    module = Path(sourced(ws, f"{sys.executable} -c 'import {PACKAGE}; print({PACKAGE}.__file__)'")).resolve()
    assert module.is_relative_to(src if kind == "symlink" else prefix), module


def test_colcon_test_runs_the_suite(symlinked):
    """``colcon test`` in the symlinked workspace (it runs the sources' tests: here one fast file)."""
    ws = symlinked
    colcon(ws, "test", "--pytest-args", "test/test_ros_package.py", "-q")
    result = colcon(ws, "test-result", "--all", "--verbose")
    summary = result.strip().splitlines()[-1]
    assert summary.startswith("Summary:") and " 0 errors, 0 failures" in summary, result
    assert int(summary.split()[1]) >= 10, result   # the file's tests ran


def test_installed_sim_node_answers_a_topic(symlinked):
    """``sim_node`` as ``ros2 run tensegrity_sim sim_node`` starts it (the ament index's prefix, its
    lib/tensegrity_sim), with the built-in prism3, publishes node poses that an rclpy peer here receives.
    From the symlinked workspace, where the copied kernel cache is valid (a plain install compiles anew)."""
    ws = symlinked
    prefix = sourced(ws, f"{sys.executable} -c \"from ament_index_python.packages import get_package_prefix as p; "
                         f"print(p('{PACKAGE}'))\"")
    node = Path(prefix) / "lib" / PACKAGE / "sim_node"
    command = f". ./install/setup.sh && exec {node} --ros-args -p scene:=prism3 -p method:=elastic " \
              f"-p log_path:={ws / 'node.mcap'}"
    context = rclpy.Context()
    rclpy.init(context=context)
    peer = rclpy.create_node("colcon_peer", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(peer)
    poses = []
    topic, _ = NODE_OUTPUTS["node_poses"]
    peer.create_subscription(PoseArray, topic, poses.append, 10)
    proc = subprocess.Popen(["sh", "-c", command], cwd=ws, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)
    try:
        end = time.monotonic() + 240   # a cold kernel cache compiles first (tens of seconds)
        while len(poses) < 3 and time.monotonic() < end and proc.poll() is None:
            executor.spin_once(timeout_sec=0.1)
    finally:
        proc.terminate()
        output = proc.communicate(timeout=30)[0]
        executor.shutdown()
        peer.destroy_node()
        rclpy.try_shutdown(context=context)
    assert len(poses) >= 3, output[-4000:]
    assert len(poses[-1].poses) == 6 and poses[-1].header.frame_id == "world"
    assert (ws / "node.mcap").stat().st_size > 0
