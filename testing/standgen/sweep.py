"""Cases of the identification sweep and their scoring (pure: no bag, no calibration run).

A case is a stand configuration with a known true effect set. Its outcome is the set of
effects the calibration accepted (``None`` when the calibration failed) with its held-out RMS
and noise floor. :func:`summarise` turns outcomes into the confusion tables.

Three kinds of case: ``registry`` (clean, every registry family alone, pairs), ``fault`` (a
recording fault of :data:`~standgen.ranges.FAULT_FAMILIES` on the clean law, or an
independently driven grid) and ``unlisted`` (an effect of
:data:`~standgen.ranges.UNLISTED_FAMILIES`, in no list of the product's registry).
:func:`score` reads a calibration.json defensively (an older one without ``health``,
``verdict`` or ``discovered`` scores as "not found") into the columns of the fault and
unlisted tables.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import asdict, dataclass, field
from itertools import combinations
from typing import Any, Final

import numpy as np

from standgen.effects import draw_effects
from standgen.faults import Faults, draw_fault
from standgen.ranges import FAMILIES, FAULT_FAMILIES, UNLISTED_FAMILIES
from standgen.stand import TEMPERATURE_KINDS, StandConfig, mid_temperature, true_law
from standgen.unlisted import Unlisted, draw_unlisted

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
#: Repeats of every fault and every unlisted family: full and quick sweep.
FAULT_REPEATS: Final = {"full": 2, "quick": 1}
UNLISTED_REPEATS: Final = {"full": 2, "quick": 1}
#: Length [s] of fault and unlisted cases (long enough for 30 ppm to move the stamps by
#: about a period at 1 kHz, short enough for the sweep's 20 minutes).
FAULT_DURATION_S: Final = 30.0
#: Conditions of fault cases per repeat: (rate [Hz], grid).
FAULT_CONDITIONS: Final = {
    "clock_rate": ((1000.0, (2, 2)), (2000.0, (1, 1))),
    "sensor_frozen": ((500.0, (4, 4)), (1000.0, (2, 2))),
    "sensor_flat": ((1000.0, (2, 2)), (500.0, (4, 4))),
    "sensor_jump": ((500.0, (4, 4)), (1000.0, (3, 3))),
    "actuator_weak": ((500.0, (4, 4)), (1000.0, (3, 3))),
    "actuator_dead": ((1000.0, (3, 3)), (500.0, (4, 4))),
    "receive_jitter": ((1000.0, (1, 1)), (500.0, (2, 2))),
    "independent_drive": ((250.0, (8, 8)), (500.0, (4, 4))),
}
#: Conditions of unlisted cases per repeat: (rate [Hz], grid).
UNLISTED_CONDITIONS: Final = {
    "slew_limit": ((1000.0, (1, 1)), (500.0, (2, 2))),
    "amplifier_droop": ((500.0, (2, 2)), (1000.0, (1, 1))),
    "periodic_nonlinearity": ((1000.0, (1, 1)), (500.0, (2, 2))),
    "creep": ((500.0, (2, 2)), (1000.0, (1, 1))),
    "thermal_gradient": ((500.0, (4, 4)), (500.0, (3, 3))),
}
#: Tolerances of "named": clock rate [ppm] (or this share of it, the larger), a weak
#: actuator's gain fraction, a freeze instant [s], margin [s] around a late burst.
CLOCK_TOLERANCE_PPM: Final = 5.0
CLOCK_TOLERANCE_SHARE: Final = 0.15
WEAK_TOLERANCE: Final = 0.1
FREEZE_TOLERANCE_S: Final = 2.0
BURST_MARGIN_S: Final = 0.5
#: The law counts as right within this share (M and k at the recording's mid temperature).
LAW_TOLERANCE: Final = 0.05
#: Goal of held-out RMS after / true noise on unlisted cases.
UNLISTED_RMS_GOAL: Final = 1.3
#: The product's data-driven effect (discovered terms written into the parameters file): not
#: a registry stand-in when accepted.
DISCOVERED_EFFECT: Final = "discovered"
#: Health finding kinds that find each fault family (contract: es_calibration.output.schema).
FAULT_KINDS: Final = {
    "clock_rate": ("clock_rate",),
    "sensor_frozen": ("sensor_frozen",),
    "sensor_flat": ("sensor_flat",),
    "sensor_jump": ("sensor_jump",),
    "actuator_weak": ("actuator_weak",),
    "actuator_dead": ("actuator_dead",),
    "receive_jitter": ("receive_jitter", "late_burst"),
}


@dataclass(frozen=True)
class Case:
    """One sweep case: its name, true effect set, storage and the stand configuration."""

    name: str
    truth: tuple[str, ...]
    storage: str
    config: StandConfig

    @property
    def families(self) -> tuple[str, ...]:
        """The case's fault or unlisted families (empty for a registry case)."""
        c = self.config
        return (*c.faults.names, *(("independent_drive",) if c.independent_drive else ()),
                *c.unlisted.names)

    @property
    def kind(self) -> str:
        """``unlisted``, ``fault`` or ``registry`` (see the module docstring)."""
        if self.config.unlisted.names:
            return "unlisted"
        return "fault" if self.families else "registry"

    def describe(self) -> dict[str, Any]:
        """Return the case's conditions and true effect, fault and law parameters (JSON-ready).

        Fault cases carry ``law_mid``: the true M and k of every actuator (row-major) at the
        recording's mid temperature, and ``excluded_actuators`` (a weak or dead one) that
        the law's score leaves out.
        """
        c = self.config
        extra: dict[str, Any] = {}
        if self.kind == "fault":
            law, mid = true_law(c), mid_temperature(c)
            shape = c.shape
            extra["law_mid"] = {
                "temperature_degc": mid,
                "M": np.broadcast_to(law.M(mid), shape).ravel().tolist(),
                "k": np.broadcast_to(law.k(mid), shape).ravel().tolist(),
            }
            extra["excluded_actuators"] = ([c.faults.actuator.index] if c.faults.actuator
                                           else [])
        return {
            "kind": self.kind, "families": list(self.families),
            "faults": c.faults.as_dict(), "unlisted": c.unlisted.as_dict(),
            "independent_drive": c.independent_drive, **extra,
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


def make_special_case(family: str, repeat: int, index: int, seed: int) -> Case:
    """Build repeat ``repeat`` of a fault or unlisted ``family`` (sweep case ``index``).

    The clean law otherwise (no registry effect, except coupling on the 8 x 8 independently
    driven grid, the issue's case), per-actuator sensors, 2 % of displacement messages
    dropped, no gap or hole: the fault or effect is the one thing to find.
    """
    rng = np.random.default_rng(seed)
    table = FAULT_CONDITIONS if family in FAULT_FAMILIES else UNLISTED_CONDITIONS
    rate, shape = table[family][repeat % len(table[family])]
    truth: tuple[str, ...] = ("coupling",) if family == "independent_drive" and min(
        shape) >= 8 else ()
    cells = shape[0] * shape[1]
    faults = draw_fault(family, rng, rate_hz=rate, duration_s=FAULT_DURATION_S,
                        sensors=cells, cells=cells) if family in FAULT_FAMILIES else Faults()
    unlisted = (draw_unlisted([family], rng, shape) if family in UNLISTED_FAMILIES
                else Unlisted())
    config = StandConfig(
        rows=shape[0], cols=shape[1], rate_hz=rate,
        temperature_rate_hz=TEMPERATURE_RATES_HZ[index % len(TEMPERATURE_RATES_HZ)],
        duration_s=FAULT_DURATION_S, temperature_kind="raw",
        noise_m=NOISES_M[index % len(NOISES_M)],
        sensor_noise_degc=SENSOR_NOISES_DEGC[(index // 2) % len(SENSOR_NOISES_DEGC)],
        effects=draw_effects(truth, rng, rate_hz=rate, duration_s=FAULT_DURATION_S,
                             shape=shape),
        drop_fraction=DROP_FRACTION, seed=seed,
        independent_drive=family == "independent_drive", faults=faults, unlisted=unlisted,
    )
    return Case(f"{family}-{repeat}", truth, STORAGES[index % len(STORAGES)], config)


def build_cases(quick: bool = False, seed: int = 0) -> list[Case]:
    """Return the sweep's cases; see the module constants.

    Clean cases, every family alone (repeated), every pair, every fault and unlisted family
    (repeated).
    """
    size = "quick" if quick else "full"
    sets: list[tuple[str, tuple[str, ...]]] = [
        (f"clean-{i}", ()) for i in range(CLEAN_CASES[size])]
    for repeat in range(SINGLE_REPEATS[size]):
        sets += [(f"{f}-{repeat}", (f,)) for f in FAMILIES]
    pairs = list(combinations(FAMILIES, 2))
    if quick:
        pairs = pairs[::6]
    sets += [("+".join(p), p) for p in pairs]
    cases = [make_case(name, truth, i, seed * 100_003 + i) for i, (name, truth) in
             enumerate(sets)]
    specials = [(f, r) for r in range(FAULT_REPEATS[size]) for f in FAULT_FAMILIES]
    specials += [(f, r) for r in range(UNLISTED_REPEATS[size]) for f in UNLISTED_FAMILIES]
    for i, (family, repeat) in enumerate(specials, start=len(cases)):
        cases.append(make_special_case(family, repeat, i, seed * 100_003 + i))
    return cases


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
    kind: str = "registry"
    families: tuple[str, ...] = ()
    scores: dict[str, Any] = field(default_factory=dict)

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


def _list(value: Any) -> list[Any]:
    return value if isinstance(value, list) else []


def _dict(value: Any) -> dict[str, Any]:
    return value if isinstance(value, dict) else {}


def _number(value: Any) -> float | None:
    """``value`` as a finite float, or None (missing, null, a string, NaN)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    return float(value) if np.isfinite(value) else None


def accepted_effects(doc: dict[str, Any]) -> tuple[str, ...]:
    """Return the names of the effects calibration.json accepted.

    Switched-off ones (``enabled`` false: written but not confirmed) are not accepted; an
    effect without the key (an older calibration.json) is.
    """
    return tuple(str(e["name"]) for e in _list(doc.get("effects"))
                 if isinstance(e, dict) and "name" in e and e.get("enabled", True) is not False)


def findings(doc: dict[str, Any] | None) -> list[dict[str, Any]]:
    """Return the health findings of calibration.json (none in an older one)."""
    if doc is None:
        return []
    return [f for f in _list(_dict(doc.get("health")).get("findings")) if isinstance(f, dict)]


def _named(family: str, truth: dict[str, Any], found: list[dict[str, Any]],
           health: dict[str, Any]) -> bool:
    """Whether one of the ``found`` findings names the fault ``truth`` within tolerance."""
    if family == "clock_rate":
        ppm = float(truth["ppm"])
        tolerance = max(CLOCK_TOLERANCE_PPM, CLOCK_TOLERANCE_SHARE * ppm)
        values = [_number(f.get("value")) for f in found] + [
            _number(health.get("clock_rate_ppm"))]
        return any(v is not None and abs(v - ppm) <= tolerance for v in values)
    if family.startswith("sensor_"):
        right = [f for f in found if f.get("index") == truth["sensor"]]
        if family == "sensor_frozen":
            return any((start := _number(f.get("start_s"))) is not None
                       and abs(start - float(truth["start_s"])) <= FREEZE_TOLERANCE_S
                       for f in right)
        return bool(right)
    if family.startswith("actuator_"):
        right = [f for f in found if f.get("index") == truth["index"]]
        if family == "actuator_weak":
            return any((v := _number(f.get("value"))) is not None
                       and abs(v - float(truth["fraction"])) <= WEAK_TOLERANCE for f in right)
        return bool(right)
    # receive_jitter: every true burst overlapped by a late_burst finding
    bursts = [f for f in found if f.get("kind") == "late_burst"]

    def covers(burst: list[float]) -> bool:
        start, end = burst[0] - BURST_MARGIN_S, sum(burst) + BURST_MARGIN_S
        return any((a := _number(f.get("start_s"))) is not None
                   and (b := _number(f.get("end_s"))) is not None and a <= end and b >= start
                   for f in bursts)

    return all(covers(list(b)) for b in truth["bursts"])


def law_error(description: dict[str, Any], doc: dict[str, Any] | None) -> float | None:
    """Return the worst |fitted / true - 1| of M and k at the mid temperature.

    Over the actuators not excluded (a weak or dead one); None when the law is missing or
    malformed (an older or broken calibration.json, a failed run).
    """
    truth = _dict(description.get("law_mid"))
    law = _dict(doc.get("law")) if doc is not None else {}
    if not truth or not law:
        return None
    try:
        # Tm: one value, or one per actuator (the calibration writes a row-major list)
        t_star = float(truth["temperature_degc"]) - np.asarray(law["Tm"], np.float64)
        coefficient = {n: np.asarray(law[n], np.float64) for n in
                       ("m1", "m2", "m3", "k1", "k2", "k3")}
        fit_m = coefficient["m1"] * t_star + coefficient["m2"] + coefficient["m3"] * t_star**2
        fit_k = coefficient["k1"] * t_star + coefficient["k2"] + coefficient["k3"] * t_star**2
        true_m = np.asarray(truth["M"], np.float64)
        true_k = np.asarray(truth["k"], np.float64)
        error = np.maximum(np.abs(fit_m / true_m - 1), np.abs(fit_k / true_k - 1))
    except (KeyError, TypeError, ValueError):
        return None
    if error.shape != true_m.shape:
        return None
    keep = np.ones(error.size, bool)
    keep[[i for i in _list(description.get("excluded_actuators")) if 0 <= i < keep.size]] = False
    worst = float(np.max(error[keep])) if keep.any() else None
    return worst if worst is not None and np.isfinite(worst) else None


def kept_fraction(doc: dict[str, Any] | None) -> float | None:
    """Return the share of samples the fit kept.

    ``health.kept_fraction``, else 1 - the share left out at command edges (an older
    calibration.json); None without either.
    """
    if doc is None:
        return None
    kept = _number(_dict(doc.get("health")).get("kept_fraction"))
    if kept is not None:
        return kept
    edges = _number(_dict(_dict(doc.get("data")).get("command_edges")).get("excluded_fraction"))
    return None if edges is None else 1.0 - edges


def _discovered(doc: dict[str, Any] | None) -> tuple[list[dict[str, Any]], bool, float | None]:
    """Discovered terms, whether they were added, their held-out RMS after [m]."""
    block = _dict(doc.get("discovered")) if doc is not None else {}
    terms = [t for t in _list(block.get("terms")) if isinstance(t, dict)]
    return terms, block.get("added") is True, _number(block.get("heldout_rms_after_m"))


def score(description: dict[str, Any], doc: dict[str, Any] | None) -> dict[str, Any]:
    """Return the columns of one case, read defensively.

    From its description (:meth:`Case.describe`) and its calibration.json (``None``: the
    calibration failed).

    Every case: ``stand_ins`` (accepted effects not in the truth; on an unlisted case every
    accepted registry effect; the data-driven ``discovered`` effect is none),
    ``discovered_terms`` (names). Fault cases: ``found`` and ``named``
    (None where there is nothing to find: an independently driven grid), ``law_error`` and
    ``law_within_5pct``, ``kept_fraction``, ``verdict``. Unlisted cases: ``discovered_found``,
    ``discovered_added``, ``heldout_rms_after_m`` (with the discovered terms when they were
    added, else the registry model's).
    """
    truth = set(_list(description.get("truth")))
    accepted = accepted_effects(doc) if doc is not None else ()
    terms, added, discovered_after = _discovered(doc)
    out: dict[str, Any] = {
        "stand_ins": sorted(set(accepted) - truth - {DISCOVERED_EFFECT}),
        "discovered_terms": [str(t.get("name", "?")) for t in terms],
        "verdict": (str(_dict(doc.get("verdict")).get("level", "")) or None
                    if doc is not None else None),
    }
    kind = description.get("kind", "registry")
    if kind == "fault":
        error = law_error(description, doc)
        out.update(law_error=error,
                   law_within_5pct=error is not None and error <= LAW_TOLERANCE,
                   kept_fraction=kept_fraction(doc), found=None, named=None)
        faults = _dict(description.get("faults"))
        if faults:
            family, fault_truth = next(iter(faults.items()))
            health = _dict(doc.get("health")) if doc is not None else {}
            found = [f for f in findings(doc) if f.get("kind") in FAULT_KINDS[family]]
            out.update(found=bool(found),
                       named=bool(found) and _named(family, fault_truth, found, health))
    elif kind == "unlisted":
        after = discovered_after if added and discovered_after is not None else (
            _number(doc.get("heldout_rms_after_m")) if doc is not None else None)
        true_noise = _number(description.get("true_noise_m"))
        out.update(discovered_found=bool(terms), discovered_added=added,
                   heldout_rms_after_m=after,
                   after_over_true_noise=after / true_noise if after and true_noise else None)
    return out


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
        if o.kind != "registry":
            continue
        accepted = set(o.accepted or ())
        for f in FAMILIES:
            if f in o.truth:
                table[f]["TP" if f in accepted else "FN"] += 1
            elif f in accepted:
                table[f]["FP"] += 1
    return table


def family_matrix(outcomes: list[Outcome]) -> dict[str, dict[str, int]]:
    """Return the confusion matrix: rows true families, columns accepted ones.

    Rows: true family ('none' for clean cases), then every fault and unlisted family;
    columns: accepted family or 'none'. Entry: number of cases whose true set holds the row
    family (or is empty, or whose fault or unlisted family is the row) in which the column
    family was accepted ('none': nothing accepted).
    """
    columns = (*FAMILIES, "none")
    rows = ("none", *FAMILIES, *FAULT_FAMILIES, *UNLISTED_FAMILIES)
    matrix = {row: dict.fromkeys(columns, 0) for row in rows}
    for o in outcomes:
        accepted = tuple(o.accepted or ())
        for row in (*o.truth, *o.families) or ("none",):
            for col in accepted or ("none",):
                matrix[row][col] += 1
    return matrix


def _share(outcomes: list[Outcome]) -> float | None:
    return sum(o.right for o in outcomes) / len(outcomes) if outcomes else None


def _median(values: list[float | None]) -> float | None:
    finite = [v for v in values if v is not None and np.isfinite(v)]
    return float(np.median(finite)) if finite else None


def fault_table(outcomes: list[Outcome]) -> dict[str, dict[str, int]]:
    """Return per fault family: cases, failed, found, named, stand-in, law within 5 %.

    ``to_find``: cases with a finding to make (none for an independently driven grid).
    """
    table = {f: dict.fromkeys(("cases", "failed", "to_find", "found", "named", "stand_in",
                               "law_within_5pct"), 0) for f in FAULT_FAMILIES}
    for o in outcomes:
        if o.kind != "fault":
            continue
        for family in o.families:
            row, s = table[family], o.scores
            row["cases"] += 1
            row["failed"] += o.accepted is None
            row["to_find"] += s.get("found") is not None
            row["found"] += s.get("found") is True
            row["named"] += s.get("named") is True
            row["stand_in"] += bool(s.get("stand_ins"))
            row["law_within_5pct"] += s.get("law_within_5pct") is True
    return table


def unlisted_table(outcomes: list[Outcome]) -> dict[str, dict[str, Any]]:
    """Return per unlisted family: cases, failed, stand-in, discovered, added, RMS ratios.

    Stand-in: any registry effect accepted; RMS: held-out RMS after <= 1.3x the true noise,
    and the median of that ratio.
    """
    table: dict[str, dict[str, Any]] = {}
    for family in UNLISTED_FAMILIES:
        mine = [o for o in outcomes if o.kind == "unlisted" and family in o.families]
        ratios = [o.scores.get("after_over_true_noise") for o in mine]
        table[family] = {
            "cases": len(mine), "failed": sum(o.accepted is None for o in mine),
            "stand_in": sum(bool(o.scores.get("stand_ins")) for o in mine),
            "discovered_found": sum(o.scores.get("discovered_found") is True for o in mine),
            "discovered_added": sum(o.scores.get("discovered_added") is True for o in mine),
            "within_1p3": sum(r is not None and r <= UNLISTED_RMS_GOAL for r in ratios),
            "median_after_over_true_noise": _median(ratios),
        }
    return table


def _fraction(hits: int, total: int) -> float | None:
    return hits / total if total else None


def summarise(outcomes: list[Outcome]) -> dict[str, Any]:
    """Return the sweep's figures (shares as fractions 0-1, ``None`` where no case counts).

    Clean, single and pair figures are over registry cases only; fault and unlisted cases
    have their own tables and goal figures.
    """
    registry = [o for o in outcomes if o.kind == "registry"]
    clean = [o for o in registry if not o.truth]
    single = [o for o in registry if len(o.truth) == 1]
    pair = [o for o in registry if len(o.truth) == 2]
    right = [o for o in registry if o.right]
    faults = fault_table(outcomes)
    unlisted = unlisted_table(outcomes)
    fault_cases = sum(r["cases"] for r in faults.values())
    unlisted_cases = sum(r["cases"] for r in unlisted.values())
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
        "sets": dict(Counter(f"{_label(o.truth)} -> {_label(o.accepted)}" for o in registry)),
        "families": family_counts(outcomes),
        "matrix": family_matrix(outcomes),
        "faults": faults, "fault_cases": fault_cases,
        "fault_stand_ins": sum(r["stand_in"] for r in faults.values()),
        "fault_named": _fraction(sum(r["named"] for r in faults.values()),
                                 sum(r["to_find"] for r in faults.values())),
        "fault_law_within_5pct": _fraction(
            sum(r["law_within_5pct"] for r in faults.values()), fault_cases),
        "unlisted": unlisted, "unlisted_cases": unlisted_cases,
        "unlisted_stand_ins": sum(r["stand_in"] for r in unlisted.values()),
        "unlisted_discovered": _fraction(
            sum(r["discovered_found"] for r in unlisted.values()), unlisted_cases),
        "unlisted_within_1p3": _fraction(
            sum(r["within_1p3"] for r in unlisted.values()), unlisted_cases),
        "clean_discovered": sum(bool(o.scores.get("discovered_terms")) for o in clean),
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
