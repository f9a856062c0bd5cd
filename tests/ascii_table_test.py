"""The compiled ASCII number parser: the very doubles ``float()`` gives on its fast path, ``None`` (the caller's
``loadtxt`` fallback) for anything off it."""

import numpy as np
import pytest

from rpmnet_jax.io import ascii_table


def _parse(text: str, rows: int, cols: int):
    return ascii_table.parse_rows(text.encode(), 0, rows, cols)


def test_random_decimals_parse_to_the_doubles_float_gives():
    rng = np.random.default_rng(0)
    values = rng.choice([-1.0, 1.0], 3000) * rng.uniform(1, 10, 3000) * 10.0 ** rng.integers(-6, 4, 3000)
    tokens = []
    for i, v in enumerate(values):
        fmt = ("%.6g", "%.9g", "%.15g", "%.3e", "%.10f", "%.0f")[i % 6]
        tokens.append(fmt % v)
    tokens[0], tokens[1], tokens[2], tokens[3] = "+1.5", "-0", ".25", "7."
    text = "\n".join(" ".join(tokens[r * 3:r * 3 + 3]) for r in range(1000)) + "\n"
    got = _parse(text, 1000, 3)
    assert got is not None
    expected = np.array([float(t) for t in tokens]).reshape(1000, 3)
    np.testing.assert_array_equal(got[0], expected)
    assert np.signbit(got[0][0, 1])  # -0 keeps its sign
    assert got[1] == len(text)


def test_rows_end_where_asked_and_whitespace_varies():
    text = "1 2 3\r\n\t4  5 6 \n7 8 9\nrest of the file\n"
    table, end = _parse(text, 3, 3)
    np.testing.assert_array_equal(table, [[1, 2, 3], [4, 5, 6], [7, 8, 9]])
    assert text.encode()[end:] == b"rest of the file\n"


@pytest.mark.parametrize("text", [
    "0.12345678901234567 1 2\n",  # 17 significant digits: beyond the exact path
    "nan 1 2\n", "inf 1 2\n", "1e400 1 2\n", "1e-30 1 2\n",  # not on the fast path
    "1 2\n",  # a short row
    "1 2 3 4\n",  # a long row
    "1 2 x\n", "1 2 3x\n", "1 2 -\n", "1 2 1e\n",  # malformed tokens
    "1,2,3\n",  # another separator
])
def test_anything_off_the_fast_path_returns_none(text):
    assert _parse(text, 1, 3) is None


def test_a_body_shorter_than_the_header_says_returns_none():
    assert _parse("1 2 3\n4 5 6\n", 3, 3) is None
    assert _parse("1 2 3", 1, 3) is not None  # the last row needs no newline
