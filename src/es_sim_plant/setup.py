from glob import glob

from setuptools import find_packages, setup

PACKAGE = "es_sim_plant"
# executable name (under lib/es_sim_plant/, for `ros2 run`) -> module with main()
EXECUTABLES = {
    "plant_node": "es_sim_plant.plant_node",
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
    description="Deformable-mirror plant simulator: UV heating, thermal network, actuator grid, sensors, sim time; scenarios and the plant node.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            f"{PACKAGE}-{exe.replace('_', '-')} = {module}:main"
            for exe, module in EXECUTABLES.items()
        ],
    },
)
