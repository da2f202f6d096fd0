"""What the discovery step found: its terms, the held-out errors before and after, in words."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from es_physics.effects.discovered import BY_CODE, Carrier, Term, expression, unit

#: One factor of a library term: (factor code, its parameter), see es_physics FACTORS.
FactorKey = tuple[int, float]


@dataclass(frozen=True)
class DiscoveredTerm:
    """One selected library term (calibration.json ``discovered.terms``).

    Attributes:
        name: ``discovered_<k>`` in selection order.
        factors: its one or two (factor code, parameter) pairs.
        coefficient: fitted on the training rows [``unit``].
        share: part of the held-out mean-square error before discovery it removed (in
            selection order: the cut it added).
        halves: its coefficient fitted on each half of the record (time order).
        stable: both halves agree with ``coefficient`` (see regression.STABILITY).
        acts_on: where the term adds (the displacement, the drive or the law's temperature).
        used: the model is refitted with it and the RMS after counts it (when the step adds
            the terms); it is written into the parameters file unless it acts on the
            measurement (:attr:`written`).
        parameter_halves: its factor's parameter fitted on each half of the record, where
            the step searches it there (a slew-rate limit [V/s]), else None.

    """

    name: str
    factors: tuple[FactorKey, ...]
    coefficient: float
    share: float
    halves: tuple[float, float]
    stable: bool
    acts_on: Carrier = Carrier.DISPLACEMENT
    used: bool = False
    parameter_halves: tuple[float, float] | None = None

    @property
    def expression(self) -> str:
        """Return the factors as text."""
        return expression(self.factors)

    @property
    def unit(self) -> str:
        """Return the coefficient's unit."""
        return unit(self.factors, self.acts_on)

    @property
    def written(self) -> bool:
        """Whether it goes into the parameters file (used, and the mirror's)."""
        return self.used and self.acts_on is not Carrier.MEASUREMENT

    @property
    def side(self) -> str:
        """Return where the term acts: "drive", "temperature" or "output".

        "drive" also for a displacement term of the present command (it needs the drive's
        inverse).
        """
        if self.acts_on is Carrier.TEMPERATURE:
            return "temperature"
        if self.acts_on is Carrier.MEASUREMENT:
            return "measurement"
        if self.acts_on is Carrier.DRIVE:
            return "drive"
        return "drive" if any(BY_CODE[c].side == "drive" for c, _ in self.factors) else "output"

    @property
    def mechanism(self) -> str:
        """Return the physical mechanism the term points to, in words."""
        words = [BY_CODE[c].mechanism for c, _ in self.factors]
        text = words[0] if len(words) == 1 or words[0] == words[1] else (
            f"a product of {words[0]}; and {words[1]}")
        if self.acts_on is Carrier.DISPLACEMENT:
            return text
        return f"an error of {self.acts_on.words} that follows {text}"

    @property
    def term(self) -> Term:
        """Return the term as the registry's discovered effect holds it."""
        b = self.factors[1] if len(self.factors) > 1 else None
        return Term(self.coefficient, self.factors[0], b, self.acts_on)

    @property
    def compensable(self) -> bool:
        """Whether the feedforward can undo it from the set point."""
        return self.term.compensable

    def as_dict(self) -> dict[str, object]:
        """Return the calibration.json form (es_calibration.output.schema)."""
        return {
            "name": self.name,
            "expression": self.expression,
            "coefficient": self.coefficient,
            "unit": self.unit,
            "share": self.share,
            "stable": self.stable,
            "halves": list(self.halves),
            "mechanism": self.mechanism,
            "side": self.side,
            "acts_on": self.acts_on.name.lower(),
            "compensable": self.compensable,
            "used": self.used,
            "written": self.written,
            "parameter_halves": (None if self.parameter_halves is None
                                 else list(self.parameter_halves)),
        }


@dataclass
class Discovery:
    """The outcome of the discovery step (all RMS on the screening block's held-out rows).

    Attributes:
        searched: the step ran (the residual stood above the noise floor).
        terms: the selected terms, in selection order.
        added: stable terms the feedforward can undo (or that act on the measurement) cut the
            held-out RMS by at least the search's least relative gain: the model is refitted
            with them, and those of the mirror are written (enabled) into the parameters file.
        heldout_rms_before_m: with the registry's effects.
        heldout_rms_after_m: with the terms used too, refitted alone (= before when none).
        heldout_rms_all_terms_m: with every selected term, written or not.
        note: why nothing was searched or found, or "" (a sentence).
        library_size: terms tried.
        seconds: the step's run time.

    """

    searched: bool
    terms: list[DiscoveredTerm] = field(default_factory=list)
    added: bool = False
    heldout_rms_before_m: float = float("nan")
    heldout_rms_after_m: float = float("nan")
    note: str = ""
    library_size: int = 0
    seconds: float = 0.0
    heldout_rms_all_terms_m: float = float("nan")

    @property
    def used(self) -> list[DiscoveredTerm]:
        """Return the terms the model is refitted with (none unless ``added``)."""
        return [t for t in self.terms if t.used] if self.added else []

    @property
    def written(self) -> list[DiscoveredTerm]:
        """Return the terms written into the parameters file (none unless ``added``)."""
        return [t for t in self.used if t.written]

    def as_dict(self) -> dict[str, object]:
        """Return calibration.json's ``discovered`` (es_calibration.output.schema)."""
        return {
            "searched": self.searched,
            "terms": [t.as_dict() for t in self.terms],
            "added": self.added,
            "heldout_rms_before_m": self.heldout_rms_before_m,
            "heldout_rms_after_m": self.heldout_rms_after_m,
            "heldout_rms_all_terms_m": self.heldout_rms_all_terms_m,
            "note": self.note,
            "library_size": self.library_size,
            "seconds": self.seconds,
        }


def with_searched_term(term: DiscoveredTerm, before_m: float, after_m: float,
                       linear: Discovery) -> Discovery:
    """Return the step's outcome with a searched ``term`` added (a slew-rate limit, a creep).

    ``term`` takes the first name and the share its cut of the held-out RMS (``before_m`` to
    ``after_m``) makes; ``linear``'s terms (the library's) stay reported, unused.
    """
    share = float(1.0 - (after_m / before_m) ** 2) if before_m > 0 else 0.0
    others = [replace(t, name=f"discovered_{k}", used=False)
              for k, t in enumerate(linear.terms, start=2)]
    return Discovery(True, [replace(term, name="discovered_1", share=share), *others], True,
                     before_m, after_m, "", linear.library_size, heldout_rms_all_terms_m=after_m)
