"""ament_python package ssf_eval (colcon build on ROS 2 Jazzy; elsewhere pip install the repository root)."""

from setuptools import find_packages, setup

PACKAGE = "ssf_eval"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + PACKAGE]),
        ("share/" + PACKAGE, ["package.xml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="SSF-PAN developers",
    maintainer_email="dev@ssf-pan.invalid",
    description="Evaluation and benchmarks of SSF-PAN: the only package that runs the simulator against the stages' cores.",
    license="Apache-2.0",
    entry_points={"ssf.commands": ["eval = ssf_eval.cli:register"]},
)
