"""Install vessel_detect: image sources, bag I/O, the camera ingest, detector and recorder nodes."""
from setuptools import find_packages, setup

PACKAGE = "vessel_detect"

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
    description="Camera ingest and ONNX vessel detector nodes.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "camera = vessel_detect.camera_node:main",
            "camera_managed = vessel_detect.camera_node:main_managed",
            "detector = vessel_detect.detector_node:main",
            "detector_managed = vessel_detect.detector_node:main_managed",
            "recorder = vessel_detect.recorder_node:main",
            "replay_detector = vessel_detect.replay_detector_node:main",
        ],
    },
)
