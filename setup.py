"""tensegrity_sim: an ament_python ROS 2 package that is also pip-installable.

This file is the one place where dependency versions are pinned. ``package.xml`` names the same
runtime dependencies for rosdep, without versions.
"""
from glob import glob

from setuptools import find_packages, setup

PACKAGE = "tensegrity_sim"

INSTALL_REQUIRES = [
    "numpy==2.4.6",
    "scipy==1.17.1",
    "PyYAML==6.0.3",
    "tqdm==4.70.1",
    # compiled stepping kernels (methods/_*_kernels.py); 0.68.1 supports numpy 2.4.6 (installed together and tested)
    "numba==0.68.1",
    # QP backends of the inextensible method (tensegrity_sim.methods.qp): DAQP is the default
    "daqp==0.11.0",
    "osqp==1.1.3",
    # MCAP logs and ROS 2 Jazzy message types without ROS (tensegrity_sim.ros)
    "mcap==1.6.0",
    "rosbags==0.11.9",
]
EXTRAS_REQUIRE = {
    "test": [
        "pytest==9.0.3",
        "mcap-ros2-support==0.6.0",  # an independent reader of the logs
        "quadprog==0.1.14",  # an independent QP solver to check the QP backends against
        "cyclonedds==11.0.1",  # the DDS transport's end-to-end tests run in CI
        "mujoco==4.0.0",      # test/test_peers.py cross-checks the elastic method against MuJoCo
        "pyarrow==26.0.1",    # test/test_sweep.py reads the sweep's Parquet tables
        "ray==2.60.0",        # test/test_sweep.py runs a sweep on a real local Ray cluster
    ],
    # Parameter sweeps (tensegrity-sim sweep): Parquet output, and Ray clusters with --address.
    "sweep": [
        "pyarrow==26.0.1",
        "ray==2.60.0",
    ],
    # Live topics without a ROS install (tensegrity-sim serve --transport dds).
    "dds": [
        "cyclonedds==11.0.1",
    ],
    "bench": [
        "matplotlib==3.11.2",
        "mujoco==4.0.0",      # the peer in bench/run_all.py
    ],
}

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*"]),
    package_data={f"{PACKAGE}.scenes": ["*.yaml"]},
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
