"""ament_python package sim_bridge (colcon build on ROS 2 Jazzy; elsewhere pip install the repository root)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "sim_bridge"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    package_data={PACKAGE: ["scenarios/*.yaml"]},
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + PACKAGE]),
        ("share/" + PACKAGE, ["package.xml"]),
        ("share/" + PACKAGE + "/launch", glob("launch/*.launch.py")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="SSF-PAN developers",
    maintainer_email="dev@ssf-pan.invalid",
    description="Closed-loop LiDAR traffic simulator with exact ground truth.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "sim_bridge = sim_bridge.node:main",
        ],
        "ssf.commands": [
            "sim = sim_bridge.cli:register",
        ],
        "ssf.scenarios": [
            "sim = sim_bridge.scenario:load_scenario",
        ],
    },
)
