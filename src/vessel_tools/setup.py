"""Install vessel_tools: the offline tools (calibration fit, training, bags, pipeline, evaluation, demo, benchmarks).

And the one `vessel` command line over them.
"""
from setuptools import find_packages, setup

PACKAGE = "vessel_tools"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    package_data={"vessel_tools.view": ["static/*"]},  # the page's own files, served by ./vessel view
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="Vessel tracking maintainers",
    maintainer_email="maintainers@vessel-tracking.invalid",
    description="Offline tools: calibration fit, training, bag building, pipeline, evaluation, demo, benchmarks.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "vessel = vessel_tools.cli:console",
            "calibrate = vessel_tools.calibrate:main",
            "demo = vessel_tools.cli:demo",
            "bench = vessel_tools.cli:bench",
            "eval = vessel_tools.cli:evaluate",
            "pipeline = vessel_tools.cli:pipeline",
            "fit = vessel_tools.cli:fit",
            "view = vessel_tools.cli:view",
            "bag_build = vessel_tools.detect.bag_build:main",
        ],
    },
)
