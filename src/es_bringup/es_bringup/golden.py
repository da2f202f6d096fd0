"""Golden bags: short reference runs of the real node graph for the regression tests.

Each :class:`GoldenCase` is a short lockstep run of plant, thermal and feedforward nodes,
recorded by the recorder exactly as the bring-up runs them. The tests (tests/system) replay
each bag's inputs through every node's core and rerun the graph live, comparing against
the bag. Regenerate only on purpose, after a change of behaviour that is meant::

    scripts/regen-golden            # = python -m es_bringup.golden --out tests/golden

It refuses to overwrite unless ``--force`` is given, and prints the size of every bag.
"""

from __future__ import annotations

import argparse
import shutil
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import NoReturn

from es_bringup.bringup import GraphConfig, ParamValue, run_graph
from es_bringup.supervisor import Outcome
from es_sim_plant.scenario import Scenario, load_scenario


@dataclass(frozen=True)
class GoldenCase:
    """One reference run: scenario, plant overrides (kept short) and feedforward mode."""

    name: str
    scenario: str
    mode: str
    plant: dict[str, ParamValue] = field(default_factory=dict)
    description: str = ""

    def load(self) -> Scenario:
        """Return the scenario as the plant node builds it from this case's parameters."""

        def number(name: str) -> float | None:
            value = self.plant.get(name)
            return float(value) if isinstance(value, int | float) else None

        rows, cols = number("rows"), number("cols")
        return load_scenario(self.scenario).with_overrides(
            rows=None if rows is None else int(rows),
            cols=None if cols is None else int(cols),
            duration=number("duration"),
        )

    def config(
        self, bag: Path | None, log_dir: Path, namespace: str | None = None
    ) -> GraphConfig:
        """Return the bring-up configuration of this case."""
        return GraphConfig(
            scenario=self.scenario,
            mode=self.mode,
            bag=bag,
            log_dir=log_dir,
            plant=dict(self.plant),
            namespace=namespace,
            wall_timeout=120.0,
        )


#: The golden cases: one actuator through a temperature step, and a small exposed grid with
#: the stateful observer mode. A few hundred steps each, a few tens of kB per bag.
CASES: tuple[GoldenCase, ...] = (
    GoldenCase(
        "thesis_ac_step",
        "thesis_ac",
        "inverse_hyperbolic",
        {"duration": 4.0},
        "thesis_ac, first 4 s (step 40 -> 42 degC at 3 s), 1 actuator",
    ),
    GoldenCase(
        "dm_exposure_4x4",
        "dm_exposure",
        "observer",
        {"duration": 2.0, "rows": 4, "cols": 4},
        "dm_exposure on a 4 x 4 grid, first 2 s (exposure starts at 0.5 s), observer mode",
    ),
)

#: Where the golden bags live, relative to the repository root (scripts/regen-golden's cwd).
DEFAULT_DIR = Path("tests/golden")


def record(
    case: GoldenCase, out_dir: Path, log_root: Path, namespace: str | None = None
) -> Outcome:
    """Run ``case`` and record it into ``out_dir/<case.name>`` (which must not exist)."""
    return run_graph(case.config(out_dir / case.name, log_root / case.name, namespace))


class _OneLineParser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message}\n")


def main(argv: Sequence[str] | None = None) -> int:
    """Regenerate the golden bags; return the exit code."""
    parser = _OneLineParser(prog="regen-golden", description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=DEFAULT_DIR, help="golden bag folder")
    parser.add_argument("--force", action="store_true", help="replace existing golden bags")
    parser.add_argument("--log-dir", type=Path, default=Path("log/golden"))
    ns = parser.parse_args(list(sys.argv[1:] if argv is None else argv))
    existing = [c.name for c in CASES if (ns.out / c.name).exists()]
    if existing and not ns.force:
        parser.error(f"{', '.join(existing)} exist in {ns.out}; give --force to replace them")
    ns.out.mkdir(parents=True, exist_ok=True)
    staging = ns.out / ".staging"
    shutil.rmtree(staging, ignore_errors=True)
    staging.mkdir()
    try:
        for case in CASES:
            outcome = record(case, staging, ns.log_dir)
            if outcome.exit_code != 0:
                print(f"regen-golden: {case.name} failed: {outcome.reason}", file=sys.stderr)
                return 1
        for case in CASES:
            shutil.rmtree(ns.out / case.name, ignore_errors=True)
            (staging / case.name).rename(ns.out / case.name)
            size = sum(p.stat().st_size for p in (ns.out / case.name).iterdir())
            print(f"{ns.out / case.name}: {size / 1024:.0f} kB ({case.description})")
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
