from setuptools import find_packages, setup

PACKAGE = "es_common"
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
    description="What every es_dm package shares below its own layer: the array type aliases and the lazy public face of a package (pure Python, numpy only, no ROS).",
    license="Apache-2.0",
)
