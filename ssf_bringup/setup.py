"""ament_python package ssf_bringup (colcon build on ROS 2 Jazzy; elsewhere pip install the repository root)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "ssf_bringup"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    package_data={PACKAGE: ["graphs/*.yaml"]},
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + PACKAGE]),
        ("share/" + PACKAGE, ["package.xml"]),
        ("share/" + PACKAGE + "/launch", glob("launch/*.launch.py")),
        ("share/" + PACKAGE + "/graphs", glob(PACKAGE + "/graphs/*.yaml")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="SSF-PAN developers",
    maintainer_email="dev@ssf-pan.invalid",
    description="The SSF-PAN application: the ssf command line, ssf demo, ssf launch, the graphs and their launch files.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "ssf = ssf_bringup.cli:main",
        ],
        "ssf.commands": [
            "bringup = ssf_bringup.commands:register",
        ],
    },
)
