"""Numbers for a person: four significant digits, never an exponent for a large number, the same text on the
terminal and in the HTML report; matrices in fixed six-decimal columns."""

import numpy as np

from rpmnet_jax.report import formats, pages


def test_number_keeps_four_significant_digits():
    assert formats.number(1.60559e-05) == "1.606e-05"  # a small confidence is not 0.000
    assert formats.number(0.8731) == "0.8731"
    assert formats.number(np.float32(0.5)) == "0.5"
    assert formats.number(0.98512) == "0.9851"
    assert formats.number(12.3456) == "12.35"
    assert formats.number(0.0) == "0"
    assert formats.number(float("nan")) == "nan"


def test_number_never_writes_a_large_number_with_an_exponent():
    assert formats.number(1234.4) == "1234"
    assert formats.number(9999.7) == "10000"  # ".4g" would give 1e+04
    assert formats.number(4_100_000.25) == "4100000"
    assert formats.number(-12345.6) == "-12346"


def test_matrix_is_fixed_columns():
    text = formats.matrix([[1, 0, 0, 2.5], [0, -1, 0, -0.25]])
    assert text.splitlines() == [" 1.000000  0.000000  0.000000  2.500000",
                                 " 0.000000 -1.000000  0.000000 -0.250000"]


def test_page_writes_numbers_as_the_terminal_does():
    text = pages.numbers_html({"confidence": 1.60559e-05, "p_wrong": np.float64(0.98512), "time (s)": 12.3456,
                               "transform": np.eye(4)})
    assert "<td>1.606e-05</td>" in text and "<td>0.9851</td>" in text and "<td>12.35</td>" in text
    assert formats.matrix(np.eye(4)) in text
