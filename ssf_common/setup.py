"""ament_python package ssf_common (colcon build on ROS 2 Jazzy; elsewhere pip install the repository root)."""

from setuptools import find_packages, setup

PACKAGE = "ssf_common"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    package_data={PACKAGE: ["middleware/*.xml"]},
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + PACKAGE]),
        ("share/" + PACKAGE, ["package.xml"]),
        ("share/" + PACKAGE, ["ssf_common/middleware/cyclone.xml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="SSF-PAN developers",
    maintainer_email="dev@ssf-pan.invalid",
    description="Middleware layer, message bindings, PointCloud2 and numpy, bags, config, geometry and the command-line contract of SSF-PAN.",
    license="Apache-2.0",
)
