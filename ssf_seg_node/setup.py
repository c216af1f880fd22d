"""ament_python package ssf_seg_node (colcon build on ROS 2 Jazzy; elsewhere pip install the repository root)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "ssf_seg_node"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    package_data={PACKAGE: ["weights/*.pt", "weights/*.md"]},
    include_package_data=True,
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + PACKAGE]),
        ("share/" + PACKAGE, ["package.xml"]),
        ("share/" + PACKAGE + "/launch", glob("launch/*.launch.py")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="SSF-PAN developers",
    maintainer_email="dev@ssf-pan.invalid",
    description="Motion segmentation of points and flow, and the flow/segmentation fusion loop.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "ssf_seg_node = ssf_seg_node.node:main",
            "ssf_fusion_node = ssf_seg_node.fusion_node:main",
        ],
        "ssf.commands": [
            "seg-train = ssf_seg_node.train_cli:register",
        ],
    },
)
