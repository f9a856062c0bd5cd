"""experiments.network_trust: how its summary counts the weak answers each rule trusts."""

from experiments import network_trust


def _rec(kind="scans", fitness=0.5, ambiguous=False, p_wrong=0.001, distinct=1, error_deg=0.3, init="classical",
         starts=4):
    return {"kind": kind, "fitness": fitness, "ambiguous": ambiguous, "p_wrong": p_wrong, "distinct": distinct,
            "error_deg": error_deg, "init": init, "starts": starts}


def test_summary_counts_weak_trusted_and_wrong_answers_per_rule():
    records = [
        _rec(),                                  # weak, unopposed, sure, right: every rule trusts it
        _rec(distinct=4, error_deg=45.7),        # weak, sure but opposed and wrong: only the doubt model trusts it
        _rec(distinct=2, starts=3),              # opposed, but RANSAC decided (3 of 4 refined): not "unopposed"
        _rec(p_wrong=0.12),                      # below the default bar (0.15), above 0.1: trusted at the default
        _rec(fitness=0.4, error_deg=150.0),      # below the floor: neither
        _rec(p_wrong=0.3, error_deg=9.0),        # in doubt: neither
        _rec(ambiguous=True, distinct=2),        # ambiguous: weak, trusted by neither
        _rec(fitness=0.8),                       # strong: not weak
        _rec(init="identity", error_deg=90.0),   # no classical hypothesis: auto runs the network, never trusted
        _rec(kind="crops", error_deg=8.0),       # another kind, counted apart
    ]
    rows = {(r["kind"], r["rule"]): r for r in network_trust.summary(records)}
    alone, unopposed = rows[("scans", "doubt model")], rows[("scans", "doubt model + unopposed")]
    decided = rows[("scans", "doubt model + unopposed or decided by RANSAC")]
    assert alone["pairs"] == unopposed["pairs"] == decided["pairs"] == 9 and alone["no_hypothesis"] == 1
    assert alone["weak"] == decided["weak"] == 7 and alone["weak_wrong"] == 3
    assert (alone["trusted"], alone["trusted_wrong"]) == (4, 1)
    assert (unopposed["trusted"], unopposed["trusted_wrong"]) == (2, 0)
    assert (decided["trusted"], decided["trusted_wrong"]) == (3, 0)
    assert alone["bar"] == 0.15
    crops = rows[("crops", "doubt model + unopposed or decided by RANSAC")]
    assert (crops["pairs"], crops["weak"], crops["trusted"], crops["trusted_wrong"]) == (1, 1, 1, 1)
    tighter = {(r["kind"], r["rule"]): r for r in network_trust.summary(records, [0.1])}
    assert tighter[("scans", "doubt model")]["trusted"] == 3 and tighter[("scans", "doubt model")]["bar"] == 0.1
