from setuptools import find_packages, setup

PACKAGE = "es_physics"
# A library: no executables (the table is read by tests/install).
EXECUTABLES = {}

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    package_data={PACKAGE: ["py.typed"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
    ],
    install_requires=["setuptools"],
    # `colcon test` runs pytest when pytest is a test dependency (tests: src/conftest.py)
    extras_require={"test": ["pytest"]},
    zip_safe=False,
    maintainer="es_dm developers",
    maintainer_email="es-dm@example.com",
    description="Electrostrictive actuator physics shared by plant, feedforward and calibration: parameters, laws and effects.",
    license="Apache-2.0",
)
