"""The report's banner: a line for each reason to doubt a run, none for a good one; numbers as the terminal
writes them; a scan set's banner names its scans and edges."""

from rpmnet_jax.report import alerts


def test_a_good_pair_has_no_banner():
    assert alerts.pair(fitness=0.8, low_fitness=0.3, p_wrong=0.01, likely_wrong=False, ambiguous=False) == []


def test_pair_banner_says_likely_wrong_low_fitness_and_ambiguous():
    lines = alerts.pair(fitness=0.21, low_fitness=0.3, p_wrong=0.98512, likely_wrong=True, ambiguous=True)
    assert len(lines) == 3
    assert lines[0].startswith("Likely wrong: p_wrong 0.9851 ")
    assert lines[1].startswith("Low fitness 0.21 (below 0.3)")
    assert lines[2].startswith("Ambiguous")
    assert alerts.pair(0.3, 0.3, 0.2, False, False) == []  # at the bar is not below it


def test_scans_banner_names_the_scans_and_edges():
    lines = alerts.scans(likely_wrong=["b.ply", "c.ply"], left_out=["d.ply"],
                         flagged_edges=[("b.ply", "a.ply", 0.7712)])
    assert lines[0].startswith("Likely wrong poses (2): b.ply, c.ply")
    assert lines[1] == "Flagged edge: b.ply → a.ply (p_wrong 0.7712)."
    assert lines[2].startswith("Left out (1): d.ply")
    assert alerts.scans() == []
