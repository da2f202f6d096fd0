from glob import glob

from setuptools import find_packages, setup

PACKAGE = "es_recordings"
# executable name (under lib/es_recordings/, for `ros2 run`) -> module with main()
EXECUTABLES = {"record": "es_recordings.record", "import": "es_recordings.labimport.cli"}

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    package_data={PACKAGE: ["py.typed"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"lib/{PACKAGE}", [f"scripts/{exe}" for exe in EXECUTABLES]),
        *[
            (f"share/{PACKAGE}/{d}", glob(f"{d}/*"))
            for d in ("launch", "scenarios", "config")
            if glob(f"{d}/*")
        ],
    ],
    install_requires=["setuptools"],
    # `colcon test` runs pytest when pytest is a test dependency (tests: src/conftest.py)
    extras_require={"test": ["pytest"]},
    zip_safe=False,
    maintainer="es_dm developers",
    maintainer_email="es-dm@example.com",
    description="Recordings: the recorder node (every /dm topic into a bag) and the lab importer (lab files into contract bags).",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            f"{PACKAGE}-{exe.replace('_', '-')} = {module}:main"
            for exe, module in EXECUTABLES.items()
        ],
    },
)
