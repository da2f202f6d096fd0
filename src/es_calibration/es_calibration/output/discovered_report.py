"""The report's section on the discovery step: held-out RMS before and after, the terms."""

from __future__ import annotations

from es_calibration.discovery import Discovery
from es_physics.effects.discovered import LIMITS

NM = 1e9


def discovery_lines(discovery: Discovery | None, basic_rms_m: float, floor_m: float) -> list[str]:
    """Return the markdown lines of the "Discovered terms" section."""
    text = ["## f. Discovered terms (effects in no registry list)", ""]
    if discovery is None:
        return [*text, "The discovery step did not run.", ""]
    if not discovery.searched:
        return [*text, discovery.note + ".", ""]
    text += [
        f"Held-out RMS on the screening block: basic law {basic_rms_m * NM:.3g} nm, with the "
        f"registry's effects {discovery.heldout_rms_before_m * NM:.3g} nm, with the terms "
        f"written {discovery.heldout_rms_after_m * NM:.3g} nm, with every selected term "
        f"{discovery.heldout_rms_all_terms_m * NM:.3g} nm (noise floor {floor_m * NM:.3g} nm); "
        f"{discovery.library_size} library terms searched in {discovery.seconds:.1f} s.",
        "",
    ]
    if discovery.terms:
        text += [
            "| term | coefficient | share removed | halves | stable | side | mechanism |",
            "|---|---|---|---|---|---|---|",
        ]
        for t in discovery.terms:
            halves = f"{t.halves[0]:.3g}, {t.halves[1]:.3g}" + (
                "" if t.parameter_halves is None else
                f" (limit {t.parameter_halves[0]:.4g}, {t.parameter_halves[1]:.4g})")
            text.append(
                f"| {t.expression} | {t.coefficient:.4g} {t.unit} | {100 * t.share:.0f} % | "
                f"{halves} | {'yes' if t.stable else 'no'} | {t.side} | {t.mechanism} |"
            )
        text.append("")
    written = discovery.written
    text.append(
        f"Written to the parameters file (compensation.discovered_*): "
        f"{', '.join(t.expression for t in written)}." if written
        else f"Nothing written to the parameters file: {discovery.note or 'no term'}."
    )
    limits = [t for t in written if any(c in LIMITS for c, _ in t.factors)]
    if limits:
        text.append(
            f"A limit no command beats (the law is fitted behind it; the feedforward leaves "
            f"it: set points that ask the drive to move faster are followed at the limit): "
            f"{', '.join(t.expression for t in limits)} [V/s].")
    metrology = [t for t in discovery.used if not t.written]
    if metrology:
        text.append(
            f"Errors of the measurement, not of the mirror (the model is fitted without them, "
            f"the feedforward leaves them; correct the metrology): "
            f"{', '.join(t.expression for t in metrology)}.")
    return [*text, ""]
