"""tensegrity_sim: an ament_python ROS 2 package that is also pip-installable.

Where dependency versions live (two places, each with one job):

* **here: ranges** — ``INSTALL_REQUIRES`` and ``EXTRAS_REQUIRE`` give every dependency as the range of
  versions the code supports, so that ``pip install`` fits into an existing environment (a ROS 2 Jazzy
  machine has Ubuntu 24.04's numpy 1.26.4, scipy 1.11.4, PyYAML 6.0.1, tqdm 4.66.2: the lower bounds).
  A lower bound is a version the suite passed with; an upper bound is the next release that may break
  the API (next major; next minor for 0.x releases). A new dependency is added here as a range.
* **constraints.txt: exact pins** — the one version of every dependency named here that CI installs
  (``pip install -c constraints.txt -e ".[test]"``) and that the README's reproducible install uses. A new
  dependency gets its pin there too. ``.ci/lower_bounds.py`` rewrites it with the lower bounds of
  ``INSTALL_REQUIRES`` for CI's second leg, which so tests the ranges' low ends.

``package.xml`` names the runtime dependencies for rosdep, without versions.
"""
from glob import glob

from setuptools import find_packages, setup

PACKAGE = "tensegrity_sim"

INSTALL_REQUIRES = [
    "numpy>=1.26.4,<3",
    "scipy>=1.11.4,<2",
    "PyYAML>=6.0.1,<7",
    "tqdm>=4.66.2,<5",
    # compiled stepping kernels (methods/_*_kernels.py); 0.68.1 supports numpy 1.22 to 2.5
    "numba>=0.68.1,<0.69",
    # numba's code generator, used directly for calls to C functions by address (methods/_c_calls.py);
    # the range numba 0.68 requires
    "llvmlite>=0.50.0,<0.51",
    # QP backends of the inextensible method (tensegrity_sim.methods.qp.solvers): DAQP is the default. Exactly
    # 0.11.0: the compiled path calls its C function daqp_quadprog with the struct layouts of that
    # release's headers (methods/qp/_daqp_kernels.py); another release may lay them out differently
    "daqp>=0.11.0,<0.11.1",
    "osqp>=1.1.3,<2",
    # MCAP logs and ROS 2 Jazzy message types without ROS (tensegrity_sim.ros)
    "mcap>=1.6.0,<2",
    "rosbags>=0.11.9,<0.12",
    # Looking at a run (tensegrity_sim.viz): the main job writes its figures and its 3-D page, so these are
    # core; plotly's wheel carries plotly.js, which the page embeds (offline, nothing fetched)
    "matplotlib>=3.11.2,<4",
    "plotly>=7.1.0,<8",
    # Parquet tables (a sweep's results; plot reads them)
    "pyarrow>=18.1.0,<27",  # 18.1: the oldest tested; from 26 numpy 2 is needed at run time
]
# ROS 2 Jazzy from PyPI: wheels exist for Linux x86_64 and CPython 3.11/3.12 only (none for ros2cli,
# launch or rosbag2). Elsewhere the extra installs nothing; use the "dds" extra there.
ROS_WHEELS = 'platform_system == "Linux" and platform_machine == "x86_64" and python_version >= "3.11" ' \
             'and python_version < "3.13"'
EXTRAS_REQUIRE = {
    "test": [
        "pytest>=9.0.3,<10",
        "pytest-xdist>=3.8.0,<4",  # the suite on every core, a file per worker (README's test command, CI)
        "hypothesis>=6.170.15,<7",  # property-based fuzzing of every public boundary (test/test_fuzz_*.py)
        "mcap-ros2-support>=0.6.0,<0.7",  # an independent reader of the logs
        "quadprog>=0.1.14,<0.2",  # an independent QP solver to check the QP backends against
        "cyclonedds>=11.0.1,<12",  # the DDS transport's end-to-end tests run in CI
        "mujoco>=4.0.0,<5",      # test/test_peers.py cross-checks the elastic method against MuJoCo
        "foxglove-sdk>=0.30.3,<0.31",    # serve --foxglove is tested end to end
        "websocket-client>=1.9.2,<2",   # a WebSocket client of our own for that test (and bench/bench_view.py)
        "ray>=2.60.0,<3",        # test/test_sweep.py runs a sweep on a real local Ray cluster
        "gymnasium>=1.4.0,<2",   # test/test_envs.py: the environments, Gymnasium's checker
        "cma>=4.5.0,<5",         # test/test_gait.py: optimize-gait's CMA-ES
    ],
    # Learning and optimising gaits (tensegrity_sim.envs, tensegrity-sim optimize-gait): Gymnasium environments
    # and CMA-ES; the gradient search takes the "jax" extra too.
    "learn": [
        "gymnasium>=1.4.0,<2",
        "cma>=4.5.0,<5",
    ],
    # Training a policy on the JAX environment (examples/train_roll.py): rejax's PPO, which takes gymnax's
    # environment class; gymnax 0.0.9 is the one that keeps Gymnasium 1.4 (1.0 asks for Gymnasium < 1.4).
    # Takes the "jax" extra too. 0.x: the next minor may break the API.
    "train": [
        "rejax>=0.1.3,<0.2",
        "gymnax>=0.0.9,<0.1",
    ],
    # Live to Foxglove without ROS (tensegrity-sim serve --foxglove).
    "foxglove": [
        "foxglove-sdk>=0.30.3,<0.31",
    ],
    # Parameter sweeps on Ray clusters (tensegrity-sim sweep --address); Parquet (pyarrow) is a core dependency.
    "sweep": [
        "ray>=2.60.0,<3",
    ],
    # Live topics without a ROS install (tensegrity-sim serve --transport dds).
    "dds": [
        "cyclonedds>=11.0.1,<12",
    ],
    # The real rclpy node (sim_node, serve) with no ROS install: rclpy, rcl, Fast DDS and the node's messages.
    "ros": [f"{wheel}>={low},<{high}; {ROS_WHEELS}" for wheel, low, high in (
        ("ros-jazzy-rclpy[fastrtps]", "7.1.6", "8"),
        ("ros-jazzy-std-msgs", "5.3.6", "6"),
        ("ros-jazzy-std-srvs", "5.3.6", "6"),
        ("ros-jazzy-geometry-msgs", "5.3.6", "6"),
        ("ros-jazzy-sensor-msgs", "5.3.6", "6"),
        ("ros-jazzy-visualization-msgs", "5.3.6", "6"),
        ("ros-jazzy-diagnostic-msgs", "5.3.6", "6"),
        ("ros-jazzy-rosgraph-msgs", "2.0.3", "3"),
    )],
    # Building the ROS package as a ROS user does, without a ROS install (test/test_colcon.py, CI's ROS leg):
    # colcon build/test/test-result of an ament_python package (colcon-ros reads package.xml; ament_package,
    # which only ament_cmake packages need, is not required). 0.x: the next minor may break the API.
    "colcon": [
        "colcon-core>=0.21.3,<0.22",
        "colcon-ros>=0.5.0,<0.6",
        "colcon-python-setup-py>=0.2.9,<0.3",
        "colcon-test-result>=0.3.8,<0.4",
    ],
    "bench": [
        "mujoco>=4.0.0,<5",      # the peer in bench/run_all.py (matplotlib is a core dependency)
        "gymnasium>=1.4.0,<2",   # bench/bench_envs.py: Gymnasium's MujocoEnv and SyncVectorEnv, the envs' peers
        "imageio>=2.38.2,<3",    # what gymnasium.envs.mujoco imports (its renderer)
    ],
    # Robots from MJCF files (tensegrity_sim.load_mjcf, tensegrity-sim import ROBOT.xml): MuJoCo's own parser.
    # Writing MJCF (Scene.to_mjcf) and reading NTRT YAML need nothing more.
    "io": [
        "mujoco>=4.0.0,<5",
    ],
    # The documentation site (mkdocs.yml, docs/): mkdocs build --strict, run by test/test_docs.py in CI
    "docs": [
        "mkdocs>=1.6.1,<2",
        "mkdocs-material>=9.8.2,<10",
        "mkdocstrings>=1.0.8,<2",
        "mkdocstrings-python>=2.0.11,<3",   # the API reference from the docstrings (griffe reads the source)
        "pymdown-extensions>=13.1.2,<14",   # maths (arithmatex) and includes of msg_docs/ and CHANGELOG.md (snippets)
    ],
    # The elastic method in JAX (backend="jax", gradients, tensegrity-sim fit), on CPU. On an NVIDIA GPU install
    # JAX's CUDA wheels instead (docs/jax.md): pip install "jax[cuda13]==0.10.2" ("jax[cuda12]" for a CUDA 12
    # driver). 0.x: the next minor may break the API.
    "jax": [
        "jax>=0.10.2,<0.11",
        "jaxlib>=0.10.2,<0.11",
    ],
}

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*"]),
    package_data={f"{PACKAGE}.scenes": ["*.yaml"], f"{PACKAGE}.schedules": ["*.yaml"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/launch", glob("launch/*.launch.py")),
        (f"share/{PACKAGE}/config", glob("config/*.yaml")),
        (f"share/{PACKAGE}/msg_docs", glob("msg_docs/*.md")),
    ],
    python_requires=">=3.10",
    install_requires=INSTALL_REQUIRES,
    extras_require=EXTRAS_REQUIRE,
    zip_safe=True,
    maintainer="tensegrity_sim developers",
    maintainer_email="dev@tensegrity-sim.invalid",
    description="Tensegrity dynamics with slack and snapping cables, member contacts, MCAP logs.",
    license="Apache-2.0",
    tests_require=["pytest"],
    entry_points={
        "console_scripts": [
            "tensegrity-sim = tensegrity_sim.cli:main",
            "sim_node = tensegrity_sim.ros.rclpy_node:main",
        ],
    },
)
