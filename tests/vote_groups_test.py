"""Step 3c of ``align_scans`` on simulated site stations: a group of unplaced scans is placed where two edges from
different members to different placed scans agree, and a wrong edge inside the group that carried a member onto
a look-alike place is cut where the placed scans' free space contradicts it (that member stays unplaced)."""

import numpy as np
import pytest

from rpmnet_jax.multiway import options as options_lib, scan_alignment
from rpmnet_jax.pair_edges import edges as edges_lib, pair_engine
from rpmnet_jax.simulation import sites


@pytest.fixture(scope="module")
def street():
    """Seven stations of two streets that cross by station 0: 2, 4, 6 along one, 1, 3, 5 along the other."""
    _, stations = sites.stations(7, seed=0, step_deg=1.0)
    truth = np.stack([s.pose for s in stations])
    with pair_engine.PairEngine(None, None) as engine:
        run = scan_alignment._prepare(engine, [s.points for s in stations], None, [np.zeros(3)] * 7,
                                      options_lib.ScanOptions(), None, None, None, None)
    return run, np.linalg.inv(truth[0]) @ truth


def _measure(run, i, j, transform):
    return edges_lib.measure(run.scans, i, j, transform, run.max_dist, "classical")


def _turn(pose, deg):
    """``pose`` turned by ``deg`` about the vertical through its own origin (its sensor)."""
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    turn = np.eye(4)
    turn[:2, :2] = [[c, -s], [s, c]]
    return pose @ turn


def _true(run, truth, i, j):
    return _measure(run, i, j, np.linalg.inv(truth[j]) @ truth[i])


def _setup(run, truth, carried_to):
    """Scans 0, 2, 4, 6 placed at the truth; 1, 3, 5 unplaced, 5 joined to 3 by an edge that puts it at
    ``carried_to``; the true edges 1 → 0 and 3 → 2 to the placed scans."""
    run.poses = np.full_like(truth, np.nan)
    run.poses[::2] = truth[::2]
    run.edges = [_true(run, truth, 2, 0), _true(run, truth, 4, 2), _true(run, truth, 6, 4)]
    inside = [_true(run, truth, 1, 3), _measure(run, 5, 3, np.linalg.inv(truth[3]) @ carried_to)]
    across = [_true(run, truth, 1, 0), _true(run, truth, 3, 2)]
    run.pair_edges = run.edges + inside + across
    run.rejected = []
    return inside


def test_a_voted_group_is_placed_at_the_truth(street):
    run, truth = street
    _setup(run, truth, truth[5])
    assert scan_alignment._vote_groups(run)
    np.testing.assert_allclose(run.poses[1::2], truth[1::2], atol=1e-6)
    assert run.rejected == []


def test_a_member_carried_onto_a_placed_scan_s_place_is_cut_off(street):
    run, truth = street
    inside = _setup(run, truth, _turn(truth[4], 180.0))  # 5 said to stand where 4 stands, turned round
    assert scan_alignment._vote_groups(run)
    np.testing.assert_allclose(run.poses[[1, 3]], truth[[1, 3]], atol=1e-6)
    assert np.isnan(run.poses[5, 0, 0])
    assert [(e.source, e.target) for e in run.rejected] == [(5, 3)]
    assert inside[1] not in run.pair_edges


def test_a_group_with_one_edge_across_stays_unplaced(street):
    run, truth = street
    _setup(run, truth, truth[5])
    run.pair_edges = run.pair_edges[:-1]  # only 1 → 0 across
    assert not scan_alignment._vote_groups(run)
    assert np.isnan(run.poses[1::2, 0, 0]).all()


def test_the_refinement_s_edges_do_not_hide_a_conflict_at_the_final_poses(street):
    """Step 5b: a scan the answer puts where a placed scan stands, turned round, is named; an edge the refinement
    measured between the two at those poses does not exempt them (it was never checked), an edge from before the
    refinement does."""
    run, truth = street
    run.poses = truth.copy()
    run.poses[5] = _turn(truth[4], 180.0)
    measured = _measure(run, 5, 4, np.linalg.inv(run.poses[4]) @ run.poses[5])  # the refinement's edge
    for screened, exempt in (([], False), ([measured], True)):
        run.edges, run.screened, run.likely_wrong = [measured], screened, set()
        scan_alignment._name_conflicts(run)
        assert 5 in run.likely_wrong and (4 in run.likely_wrong) != exempt
        assert not run.likely_wrong & {1, 3}  # at the truth, near 5's true place: no conflict
