"""Install vessel_calib: geodesy, the camera model, the calibration fit and the parameter files."""
from glob import glob

from setuptools import find_packages, setup

PACKAGE = "vessel_calib"

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
    description="GPS-only camera calibration for monocular vessel tracking.",
    license="Apache-2.0",
)
