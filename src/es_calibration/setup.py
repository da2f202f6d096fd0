from setuptools import find_packages, setup

PACKAGE = "es_calibration"
# executable name (under lib/es_calibration/, for `ros2 run`) -> module with main()
EXECUTABLES = {
    "calibrate": "es_calibration.calibrate",
}

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    package_data={PACKAGE: ["py.typed"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"lib/{PACKAGE}", [f"scripts/{exe}" for exe in EXECUTABLES]),
    ],
    install_requires=["setuptools"],
    # `colcon test` runs pytest when pytest is a test dependency (tests: src/conftest.py)
    extras_require={"test": ["pytest"]},
    zip_safe=False,
    maintainer="es_dm developers",
    maintainer_email="es-dm@example.com",
    description="Calibration of the actuator model from test-stand recordings: effect search, report, feedforward parameters.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            f"{PACKAGE}-{exe.replace('_', '-')} = {module}:main"
            for exe, module in EXECUTABLES.items()
        ],
    },
)
