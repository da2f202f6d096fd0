"""Cases of the identification sweep and their scoring (pure: no bag, no calibration run).

A case is a stand configuration with a known true effect set. Its outcome is the set of
effects the calibration accepted (``None`` when the calibration failed) with its held-out RMS
and noise floor. :func:`summarise` turns outcomes into the confusion tables.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import asdict, dataclass, field
from itertools import combinations
from typing import Any, Final

import numpy as np

from standgen.effects import draw_effects
from standgen.ranges import FAMILIES
from standgen.stand import TEMPERATURE_KINDS, StandConfig

#: Conditions the cases cycle through (each case takes the next of every list).
RATES_HZ: Final = (250.0, 500.0, 1000.0, 2000.0, 5000.0)
GRIDS: Final = ((1, 1), (2, 2), (4, 4), (1, 1), (8, 8), (3, 2))
TEMPERATURE_RATES_HZ: Final = (10.0, 1.0, 50.0, 5.0, 100.0, 20.0)
STORAGES: Final = ("mcap", "sqlite3")
NOISES_M: Final = (0.5e-9, 0.3e-9, 0.8e-9, 1.0e-9, 0.4e-9)
SENSOR_NOISES_DEGC: Final = (0.02, 0.01, 0.03)
#: Largest grid cell count per command rate (keeps every case to seconds of calibration).
MAX_CELLS: Final = {250.0: 64, 500.0: 64, 1000.0: 16, 2000.0: 6, 5000.0: 4}
#: Share of displacement messages dropped in every case.
DROP_FRACTION: Final = 0.02
#: Clean-case seeds, repeats of every single family: full and quick sweep.
CLEAN_CASES: Final = {"full": 24, "quick": 3}
SINGLE_REPEATS: Final = {"full": 3, "quick": 1}


@dataclass(frozen=True)
class Case:
    """One sweep case: its name, true effect set, storage and the stand configuration."""

    name: str
    truth: tuple[str, ...]
    storage: str
    config: StandConfig

    def describe(self) -> dict[str, Any]:
        """Return the case's conditions and true effect parameters (JSON-ready)."""
        c = self.config
        return {
            "name": self.name, "truth": list(self.truth), "storage": self.storage,
            "grid": [c.rows, c.cols], "rate_hz": c.rate_hz,
            "temperature_rate_hz": c.temperature_rate_hz, "temperature_kind": c.temperature_kind,
            "duration_s": c.duration_s, "true_noise_m": c.noise_rms_m,
            "drop_fraction": c.drop_fraction,
            "temperature_gap": list(c.temperature_gap) if c.temperature_gap else None,
            "command_holes": [list(h) for h in c.command_holes],
            "seed": c.seed, "effects": c.effects.as_dict(),
        }


def _duration(rate_hz: float) -> float:
    return 24.0 if rate_hz >= 2000 else 36.0


def make_case(name: str, truth: tuple[str, ...], index: int, seed: int) -> Case:
    """Build case number ``index`` (which picks its conditions) with effects ``truth``.

    Every case drops :data:`DROP_FRACTION` of the displacement messages; two cases in three
    have a gap of 12-20 % of the run in the temperature topic, one in seven a 50 ms hole in
    the command topic.
    """
    rng = np.random.default_rng(seed)
    rate = RATES_HZ[index % len(RATES_HZ)]
    grids = [g for g in GRIDS if g[0] * g[1] <= MAX_CELLS[rate]]
    if "coupling" in truth:
        grids = [g for g in grids if min(g) >= 2]
    shape = grids[index % len(grids)]
    duration = _duration(rate)
    gap = None
    if index % 3 != 2:
        length = float(rng.uniform(0.12, 0.2)) * duration
        gap = (float(rng.uniform(0.15, 0.85 - length / duration)) * duration, length)
    holes = ((float(rng.uniform(0.2, 0.8)) * duration, 0.05),) if index % 7 == 3 else ()
    config = StandConfig(
        rows=shape[0], cols=shape[1], rate_hz=rate,
        temperature_rate_hz=TEMPERATURE_RATES_HZ[index % len(TEMPERATURE_RATES_HZ)],
        duration_s=duration,
        temperature_kind=TEMPERATURE_KINDS[index % len(TEMPERATURE_KINDS)],
        noise_m=NOISES_M[index % len(NOISES_M)],
        sensor_noise_degc=SENSOR_NOISES_DEGC[(index // 2) % len(SENSOR_NOISES_DEGC)],
        effects=draw_effects(truth, rng, rate_hz=rate, duration_s=duration, shape=shape),
        drop_fraction=DROP_FRACTION, temperature_gap=gap, command_holes=holes, seed=seed,
    )
    return Case(name, truth, STORAGES[index % len(STORAGES)], config)


def build_cases(quick: bool = False, seed: int = 0) -> list[Case]:
    """Clean cases, every family alone (repeated), every pair; see the module constants."""
    size = "quick" if quick else "full"
    sets: list[tuple[str, tuple[str, ...]]] = [
        (f"clean-{i}", ()) for i in range(CLEAN_CASES[size])]
    for repeat in range(SINGLE_REPEATS[size]):
        sets += [(f"{f}-{repeat}", (f,)) for f in FAMILIES]
    pairs = list(combinations(FAMILIES, 2))
    if quick:
        pairs = pairs[::6]
    sets += [("+".join(p), p) for p in pairs]
    return [make_case(name, truth, i, seed * 100_003 + i) for i, (name, truth) in
            enumerate(sets)]


@dataclass
class Outcome:
    """What the calibration made of one case (``accepted`` None: it failed, see ``error``)."""

    case: str
    truth: tuple[str, ...]
    accepted: tuple[str, ...] | None
    heldout_rms_before_m: float | None = None
    heldout_rms_after_m: float | None = None
    noise_floor_m: float | None = None
    true_noise_m: float = 0.0
    seconds: float = 0.0
    error: str = ""
    conditions: dict[str, Any] = field(default_factory=dict)

    @property
    def right(self) -> bool:
        """Whether the accepted set equals the true set (order ignored)."""
        return self.accepted is not None and set(self.accepted) == set(self.truth)

    def ratios(self) -> dict[str, float | None]:
        """Held-out RMS after / tool's noise floor, / true noise; tool floor / true noise."""
        after, floor = self.heldout_rms_after_m, self.noise_floor_m
        true = self.true_noise_m or None
        return {
            "after_over_floor": after / floor if after is not None and floor else None,
            "after_over_true_noise": after / true if after is not None and true else None,
            "floor_over_true_noise": floor / true if floor is not None and true else None,
        }

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready record of the outcome and its ratios."""
        return {**asdict(self), "right": self.right, **self.ratios()}


def _label(names: tuple[str, ...] | None) -> str:
    if names is None:
        return "(failed)"
    return "+".join(sorted(names)) or "none"


def family_counts(outcomes: list[Outcome]) -> dict[str, dict[str, int]]:
    """Per family: TP (true, accepted), FN (true, not accepted), FP (not true, accepted).

    A failed calibration counts as nothing accepted.
    """
    table = {f: {"TP": 0, "FN": 0, "FP": 0} for f in FAMILIES}
    for o in outcomes:
        accepted = set(o.accepted or ())
        for f in FAMILIES:
            if f in o.truth:
                table[f]["TP" if f in accepted else "FN"] += 1
            elif f in accepted:
                table[f]["FP"] += 1
    return table


def family_matrix(outcomes: list[Outcome]) -> dict[str, dict[str, int]]:
    """Rows: true family ('none' for clean cases); columns: accepted family or 'none'.

    Entry: number of cases whose true set holds the row family (or is empty) in which the
    column family was accepted ('none': nothing accepted).
    """
    columns = (*FAMILIES, "none")
    matrix = {row: dict.fromkeys(columns, 0) for row in ("none", *FAMILIES)}
    for o in outcomes:
        accepted = tuple(o.accepted or ())
        for row in o.truth or ("none",):
            for col in accepted or ("none",):
                matrix[row][col] += 1
    return matrix


def _share(outcomes: list[Outcome]) -> float | None:
    return sum(o.right for o in outcomes) / len(outcomes) if outcomes else None


def _median(values: list[float | None]) -> float | None:
    finite = [v for v in values if v is not None and np.isfinite(v)]
    return float(np.median(finite)) if finite else None


def summarise(outcomes: list[Outcome]) -> dict[str, Any]:
    """Return the sweep's figures (shares as fractions 0-1, ``None`` where no case counts)."""
    clean = [o for o in outcomes if not o.truth]
    single = [o for o in outcomes if len(o.truth) == 1]
    pair = [o for o in outcomes if len(o.truth) == 2]
    right = [o for o in outcomes if o.right]
    after_true = [o.ratios()["after_over_true_noise"] for o in right]
    return {
        "cases": len(outcomes),
        "failed": sum(o.accepted is None for o in outcomes),
        "single_right": _share(single), "single_cases": len(single),
        "pair_right": _share(pair), "pair_cases": len(pair),
        "clean_false_positive_rate": (
            sum(bool(o.accepted) or o.accepted is None for o in clean) / len(clean)
            if clean else None),
        "clean_cases": len(clean),
        "right_within_1p2_true_noise": (
            sum(r is not None and r <= 1.2 for r in after_true) / len(right) if right else None),
        "median_after_over_true_noise_right": _median(after_true),
        "median_after_over_floor_right": _median([o.ratios()["after_over_floor"]
                                                  for o in right]),
        "median_floor_over_true_noise": _median([o.ratios()["floor_over_true_noise"]
                                                 for o in outcomes]),
        "sets": dict(Counter(f"{_label(o.truth)} -> {_label(o.accepted)}" for o in outcomes)),
        "families": family_counts(outcomes),
        "matrix": family_matrix(outcomes),
    }


def by_condition(outcomes: list[Outcome], key: str) -> dict[str, tuple[int, int]]:
    """Right / total per value of a condition (e.g. ``rate_hz``, ``grid``, ``storage``)."""
    table: dict[str, list[int]] = {}
    for o in outcomes:
        value = o.conditions.get(key)
        label = "x".join(map(str, value)) if isinstance(value, list) else f"{value}"
        counts = table.setdefault(label, [0, 0])
        counts[0] += o.right
        counts[1] += 1
    return {k: (v[0], v[1]) for k, v in sorted(table.items())}
