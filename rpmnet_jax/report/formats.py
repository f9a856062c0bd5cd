"""How a run's numbers are written for a person: one function per kind of value, used by the terminal output of
the CLIs and by the HTML report alike, so that a number reads the same in both."""

from __future__ import annotations

import numpy as np

DIGITS = 4  # significant digits of a measured number: fitness 0.8731, p_wrong 0.985, confidence 1.606e-05


def number(value, digits: int = DIGITS) -> str:
    """``value`` with ``digits`` significant digits, trailing zeros dropped (``format(value, ".4g")``), but never
    an exponent for a large number: 12345.6 → ``12346``, 0.8731 → ``0.8731``, 1.60559e-05 → ``1.606e-05``;
    ``nan`` and ``inf`` as they are."""
    value = float(value)
    text = f"{value:.{digits}g}"
    return f"{value:.0f}" if "e+" in text else text


def matrix(values) -> str:
    """Rows of a matrix (a 4×4 transform) as lines of fixed six-decimal columns (a space where a sign may go)."""
    return "\n".join(" ".join(f"{v: .6f}" for v in row) for row in np.asarray(values, np.float64))
