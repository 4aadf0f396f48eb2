"""Install vessel_common: the plumbing every package of the project shares."""
from setuptools import find_packages, setup

PACKAGE = "vessel_common"

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
    description="Errors, paths, node support and state files shared by every vessel package.",
    license="Apache-2.0",
)
