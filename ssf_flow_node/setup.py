"""ament_python package ssf_flow_node (colcon build on ROS 2 Jazzy; elsewhere pip install the repository root)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "ssf_flow_node"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    package_data={PACKAGE: ["weights/*.pt", "weights/*.json", "weights/*.md"]},
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + PACKAGE]),
        ("share/" + PACKAGE, ["package.xml"]),
        ("share/" + PACKAGE + "/launch", glob("launch/*.launch.py")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="SSF-PAN developers",
    maintainer_email="dev@ssf-pan.invalid",
    description="Scene flow estimation between consecutive LiDAR scans (ASF-style network with mask input, learning-free rigid estimator).",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "ssf_flow_node = ssf_flow_node.node:main",
        ],
        "ssf.commands": [
            "flow = ssf_flow_node.cli:register",
        ],
    },
)
