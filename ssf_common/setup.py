"""ament_python package ssf_common (colcon build on ROS 2 Jazzy; elsewhere pip install the repository root)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "ssf_common"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    package_data={PACKAGE: ["graphs/*.yaml", "middleware/*.xml"]},
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + PACKAGE]),
        ("share/" + PACKAGE, ["package.xml"]),
        ("share/" + PACKAGE + "/launch", glob("launch/*.launch.py")),
        ("share/" + PACKAGE, ["ssf_common/middleware/cyclone.xml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="SSF-PAN developers",
    maintainer_email="dev@ssf-pan.invalid",
    description="Middleware layer, message bindings, PointCloud2 and numpy, bags, launch, config and the ssf command line of SSF-PAN.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "ssf = ssf_common.cli:main",
        ],
        "ssf.commands": [
            "common = ssf_common.commands:register",
        ],
    },
)
