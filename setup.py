"""Install every package of the colcon workspace with one `pip install` (no ROS needed)."""

from setuptools import find_packages, setup

WORKSPACE_PACKAGES = (
    "ssf_common",
    "ssf_flow_node",
    "ssf_seg_node",
    "ssf_odom_node",
    "ssf_planner_node",
    "sim_bridge",
    "ssf_eval",
    "ssf_bringup",
)


def workspace_layout() -> tuple[list[str], dict[str, str]]:
    """List each ament_python package (and its subpackages) with the folder it lives in."""
    packages: list[str] = []
    package_dir: dict[str, str] = {}
    for name in WORKSPACE_PACKAGES:
        root = f"{name}/{name}"
        package_dir[name] = root
        packages += [name] + [f"{name}.{sub}" for sub in find_packages(root)]
    # The .msg files of the ament_cmake package travel as data of ssf_common.
    packages.append("ssf_common.interfaces")
    package_dir["ssf_common.interfaces"] = "ssf_interfaces"
    return packages, package_dir


packages, package_dir = workspace_layout()
setup(packages=packages, package_dir=package_dir)
