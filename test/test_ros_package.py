"""Static checks of the ROS 2 package: package.xml's dependencies, the dependency ranges and pins, the config,
the launch file, msg_docs, and who imports what. Where the scripts and data files land (setup.cfg, setup.py's
entry points and data_files) is checked on a real colcon build: test/test_colcon.py."""
import ast
import subprocess
import sys
import xml.etree.ElementTree as ET
from dataclasses import fields
from pathlib import Path

import pytest
import setuptools
import yaml
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from packaging.version import Version

import tensegrity_sim as ts
from tensegrity_sim.ros.node_logic import SERVICES, TOPICS, NodeSettings, SimNodeLogic

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "tensegrity_sim"


@pytest.fixture(scope="module")
def setup_kwargs(monkeypatch_module):
    """The arguments setup.py passes to setuptools.setup, run from the package root."""
    captured = {}
    monkeypatch_module.setattr(setuptools, "setup", lambda **kw: captured.update(kw))
    monkeypatch_module.chdir(ROOT)
    exec(compile((ROOT / "setup.py").read_text(), "setup.py", "exec"), {"__name__": "__main__"})
    return captured


@pytest.fixture(scope="module")
def monkeypatch_module():
    with pytest.MonkeyPatch.context() as mp:
        yield mp


def imported_modules(path: Path, top_level_only: bool = False) -> set[str]:
    """Absolute module names a file imports (relative imports resolved against the package)."""
    tree = ast.parse(path.read_text())
    nodes = tree.body if top_level_only else list(ast.walk(tree))
    package = ".".join(path.relative_to(ROOT).with_suffix("").parts[:-1])
    out = set()
    for node in nodes:
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                out.add(f"{base}.{node.module}" if node.module else base)
            else:
                out.add(node.module)
    return out


def ros_packages_imported(path: Path) -> set[str]:
    stdlib_and_ours = set(sys.stdlib_module_names) | {"tensegrity_sim", "numpy"}
    return {m.split(".")[0] for m in imported_modules(path)} - stdlib_and_ours


# --------------------------------------------------------------------------- package.xml
def test_package_xml_format3_and_dependencies(setup_kwargs):
    root = ET.parse(ROOT / "package.xml").getroot()
    assert root.tag == "package" and root.get("format") == "3"
    assert root.findtext("name") == "tensegrity_sim"
    assert root.findtext("version") == ts.__version__ == setup_kwargs["version"]
    for tag in ("description", "maintainer", "license"):
        assert root.findtext(tag).strip()
    assert root.find("export").findtext("build_type") == "ament_python"
    exec_depends = {e.text for e in root.findall("exec_depend")}
    message_packages = {spec.typename.split("/")[0] for spec in TOPICS.values()}
    node_imports = ros_packages_imported(PACKAGE / "ros" / "rclpy_node.py")
    launch_imports = ros_packages_imported(ROOT / "launch" / "sim.launch.py")
    assert {"rclpy", "std_srvs", "rcl_interfaces", "launch", "launch_ros"} <= node_imports | launch_imports
    missing = (message_packages | node_imports | launch_imports | {"std_msgs", "builtin_interfaces"}) - exec_depends
    assert not missing, f"package.xml lacks exec_depend {sorted(missing)}"
    assert {"python3-numpy", "python3-scipy", "python3-yaml", "python3-tqdm"} <= exec_depends
    # every runtime dependency of setup.py is a rosdep key here or named as one that pip installs
    rosdep_keys = {"numpy": "python3-numpy", "scipy": "python3-scipy", "pyyaml": "python3-yaml", "tqdm": "python3-tqdm",
                   "numba": "python3-numba"}
    from_pypi = (ROOT / "package.xml").read_text().split("from PyPI", 1)[1].split("-->", 1)[0]
    for name in (canonicalize_name(Requirement(r).name) for r in setup_kwargs["install_requires"]):
        assert rosdep_keys.get(name) in exec_depends or name in from_pypi.split(), name
    assert "python3-pytest" in {e.text for e in root.findall("test_depend")}
    assert (ROOT / "resource" / "tensegrity_sim").is_file()


# --------------------------------------------------------------------------- dependency versions
def constraints() -> dict[str, Version]:
    pins = {}
    for line in (ROOT / "constraints.txt").read_text().splitlines():
        if line.strip() and not line.lstrip().startswith("#"):
            requirement = Requirement(line.split("#")[0])
            (spec,) = requirement.specifier
            assert spec.operator == "==", line
            assert canonicalize_name(requirement.name) not in pins, f"pinned twice: {line}"
            pins[canonicalize_name(requirement.name)] = Version(spec.version)
    return pins


def test_dependencies_are_ranges_and_constraints_pin_each_inside_its_range(setup_kwargs):
    """setup.py gives ranges (a tested lower bound, an upper bound), constraints.txt one exact version of
    each, inside the range; nothing is pinned that setup.py does not name (setup.py's docstring)."""
    requirements = [Requirement(r) for r in setup_kwargs["install_requires"] + [
        r for extra in setup_kwargs["extras_require"].values() for r in extra]]
    pins = constraints()
    for r in requirements:
        operators = {spec.operator for spec in r.specifier}
        assert operators == {">=", "<"}, f"{r}: give a range >=low,<high (exact pins go to constraints.txt)"
        assert r.specifier.contains(pins[canonicalize_name(r.name)]), f"constraints.txt pins {r.name} outside {r}"
    assert set(pins) == {canonicalize_name(r.name) for r in requirements}
    assert {"mcap", "rosbags", "mcap-ros2-support"} <= set(pins)


def test_ros_extra_only_where_the_wheels_exist(setup_kwargs):
    """The Jazzy wheels exist for Linux x86_64, CPython 3.11 and 3.12 only: the extra's marker says so."""
    ros = [Requirement(r) for r in setup_kwargs["extras_require"]["ros"]]
    assert {r.name for r in ros} >= {"ros-jazzy-rclpy", "ros-jazzy-std-srvs", "ros-jazzy-rosgraph-msgs"}
    assert next(r for r in ros if r.name == "ros-jazzy-rclpy").extras == {"fastrtps"}
    for platform, machine, python, expected in (("Linux", "x86_64", "3.11", True), ("Linux", "x86_64", "3.12", True),
                                                ("Linux", "x86_64", "3.13", False), ("Linux", "aarch64", "3.12", False),
                                                ("Darwin", "x86_64", "3.12", False), ("Windows", "AMD64", "3.12", False)):
        env = {"platform_system": platform, "platform_machine": machine, "python_version": python}
        assert all(r.marker.evaluate(env) == expected for r in ros), env


def test_ci_lower_bound_leg_pins_the_lower_bounds(setup_kwargs):
    out = subprocess.run([sys.executable, str(ROOT / ".ci" / "lower_bounds.py")], capture_output=True, text=True,
                         check=True).stdout
    lowest = {canonicalize_name(Requirement(line.split("#")[0]).name): line.split("#")[0].strip()
              for line in out.splitlines() if line.strip() and not line.startswith("#")}
    for r in map(Requirement, setup_kwargs["install_requires"]):
        low = next(spec.version for spec in r.specifier if spec.operator == ">=")
        assert lowest[canonicalize_name(r.name)] == f"{r.name}=={low}"
    assert lowest["pytest"] == f"pytest=={constraints()['pytest']}"  # the rest as constraints.txt pins them


# --------------------------------------------------------------------------- config, launch
def test_config_lists_every_parameter_with_its_default():
    params = yaml.safe_load((ROOT / "config" / "sim_node.yaml").read_text())["tensegrity_sim"]["ros__parameters"]
    assert params == NodeSettings().parameters
    assert NodeSettings(**params) == NodeSettings()


def test_launch_file_runs_sim_node_with_the_config():
    tree = ast.parse((ROOT / "launch" / "sim.launch.py").read_text())
    calls = [n for n in ast.walk(tree) if isinstance(n, ast.Call) and getattr(n.func, "id", "") == "Node"]
    assert len(calls) == 1
    kw = {k.arg: k.value for k in calls[0].keywords}
    assert {k: ast.literal_eval(kw[k]) for k in ("package", "executable", "name")} == {
        "package": "tensegrity_sim", "executable": "sim_node", "name": "tensegrity_sim"}
    strings = {n.value for n in ast.walk(tree) if isinstance(n, ast.Constant) and isinstance(n.value, str)}
    assert {"config", "sim_node.yaml"} <= strings and (ROOT / "config" / "sim_node.yaml").is_file()
    overrides = [n for n in ast.walk(kw["parameters"]) if isinstance(n, ast.Dict)]
    names = {ast.literal_eval(k) for d in overrides for k in d.keys}
    assert names and names <= set(NodeSettings().parameters)
    assert "generate_launch_description" in {n.name for n in tree.body if isinstance(n, ast.FunctionDef)}


# --------------------------------------------------------------------------- msg_docs
def test_msg_docs_one_page_per_topic():
    index = (ROOT / "msg_docs" / "README.md").read_text()
    for key, spec in TOPICS.items():
        page = ROOT / "msg_docs" / f"{key}.md"
        text = page.read_text()
        assert f"`{spec.name}`" in text.splitlines()[0] and f"`{spec.typename}`" in text, key
        assert f"({key}.md)" in index and f"`{spec.typename}`" in index
        assert "QoS" in text and ("Example" in text or key == "diagnostics" or key == "markers"), key


def test_msg_docs_services_and_parameters():
    services = (ROOT / "msg_docs" / "services.md").read_text()
    for name, method in SERVICES.items():
        assert f"`~/{name}`" in services and callable(getattr(SimNodeLogic, method))
    parameters = (ROOT / "msg_docs" / "parameters.md").read_text()
    for f in fields(NodeSettings):
        if f.name != "node_name":
            default = str(f.default).lower() if isinstance(f.default, bool) else f.default   # as YAML writes it
            assert f"| `{f.name}` |" in parameters and f"`{default}`" in parameters, f.name


# --------------------------------------------------------------------------- who imports what
def test_core_imports_no_ros_no_mcap():
    """The numerical core never imports the ROS side, rosbags, mcap or rclpy; cli.py and the package's own
    ``__init__`` (its ``fit``, which reads an MCAP log) only lazily, inside a function."""
    forbidden = ("tensegrity_sim.ros", "rosbags", "mcap", "rclpy")
    for path in PACKAGE.rglob("*.py"):
        if "ros" in path.relative_to(PACKAGE).parts:
            continue
        lazy = path.name == "cli.py" or path == PACKAGE / "__init__.py"
        modules = imported_modules(path, top_level_only=lazy)
        bad = sorted(m for m in modules if m.startswith(forbidden))
        assert not bad, f"{path.relative_to(ROOT)} imports {bad}"
    code = "import sys, tensegrity_sim, tensegrity_sim.cli; print(sorted(m for m in sys.modules " \
           "if m.startswith(('tensegrity_sim.ros', 'rosbags', 'mcap', 'rclpy'))))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT)
    assert out.stdout.strip() == "[]"


def test_only_the_node_imports_rclpy():
    for path in (PACKAGE / "ros").glob("*.py"):
        ros = {m for m in imported_modules(path) if m.split(".")[0] in
               {"rclpy", "rcl_interfaces", "std_srvs", "std_msgs", "sensor_msgs", "geometry_msgs"}}
        if path.name == "rclpy_node.py":
            assert "rclpy" in ros
        elif path.name == "messages.py":
            assert ros == {"rclpy.serialization"}  # the one-source switch, inside try/except ImportError
        else:
            assert not ros, path.name
