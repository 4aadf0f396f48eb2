"""Install vessel_bringup: the launch file of the whole graph and the graph runner behind ``./vessel graph``."""
from glob import glob

from setuptools import find_packages, setup

PACKAGE = "vessel_bringup"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/launch", glob("launch/*.launch.py")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="Vessel tracking maintainers",
    maintainer_email="maintainers@vessel-tracking.invalid",
    description="Launch file and graph runner of the vessel-tracking nodes.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "graph = vessel_bringup.graph:main",
            "host = vessel_bringup.node_host:main",
        ],
    },
)
