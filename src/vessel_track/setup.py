"""Install vessel_track: the tracker, fuser and GPS publisher nodes."""
from setuptools import find_packages, setup

PACKAGE = "vessel_track"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="Vessel tracking maintainers",
    maintainer_email="maintainers@vessel-tracking.invalid",
    description="Multi-target Kalman tracker, screen-to-world fuser and GPS publisher.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "tracker = vessel_track.tracker_node:main",
            "fuser = vessel_track.fuser_node:main",
            "gps_publisher = vessel_track.gps_publisher_node:main",
        ],
    },
)
