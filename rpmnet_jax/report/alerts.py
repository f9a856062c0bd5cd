"""What a report's banner says: one line per reason to doubt a run (a likely wrong, ambiguous or poorly fitting
answer; scans or edges flagged, scans left out), from plain numbers and names, so that a person who reads nothing
else on the page still sees it. Empty when there is nothing to say."""

from __future__ import annotations

from rpmnet_jax.report import formats


def pair(fitness: float, low_fitness: float, p_wrong: float, likely_wrong: bool, ambiguous: bool) -> list:
    """The banner of one registration: ``likely_wrong`` (``p_wrong`` at or above the doubt model's threshold, or
    the answer otherwise flagged), ``fitness`` below ``low_fitness`` (the CLI's ``--low-fitness``), ``ambiguous``."""
    lines = []
    if likely_wrong:
        lines.append(f"Likely wrong: p_wrong {formats.number(p_wrong)} (the calibrated probability that the rotation "
                     "is off). Check the clouds before using this transform.")
    if fitness < low_fitness:
        lines.append(f"Low fitness {formats.number(fitness)} (below {formats.number(low_fitness)}): only this share "
                     "of the source has a reference point within the correspondence distance.")
    if ambiguous:
        lines.append("Ambiguous: another distinct answer scores nearly as well (a shape that fits itself in several "
                     "poses); the answer may be any of the candidates below.")
    return lines


def scans(likely_wrong=(), left_out=(), flagged_edges=()) -> list:
    """The banner of a scan set: ``likely_wrong``, names of placed scans whose pose rests on a registration
    flagged likely wrong; ``left_out``, names of scans not placed; ``flagged_edges``, ``(source, target,
    p_wrong)`` of kept edges flagged likely wrong."""
    lines = []
    if likely_wrong:
        lines.append(f"Likely wrong pose{'s' if len(likely_wrong) > 1 else ''} ({len(likely_wrong)}): "
                     f"{', '.join(map(str, likely_wrong))}: placed by a registration flagged likely wrong; check "
                     f"{'them' if len(likely_wrong) > 1 else 'it'}.")
    if flagged_edges:
        named = ", ".join(f"{a} → {b} (p_wrong {formats.number(p)})" for a, b, p in flagged_edges)
        lines.append(f"Flagged edge{'s' if len(flagged_edges) > 1 else ''}: {named}.")
    if left_out:
        lines.append(f"Left out ({len(left_out)}): {', '.join(map(str, left_out))}: overlap none of the placed "
                     "scans; not in the outputs.")
    return lines
