"""Global initialisation: hypothesis coverage, the batched network call, recovery of any rotation."""

import jax
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import rpmnet_jax
from conftest import asymmetric_shape, rotation_about, rotation_error_deg
from rpmnet_jax import registration
from rpmnet_jax.pairwise import candidates, global_search, prepare
from rpmnet_jax.weights import loading


@pytest.mark.parametrize("kind,size,radius", [("icosahedral", 60, 44.4), ("octahedral", 24, 62.8)])
def test_hypotheses_are_rotations_covering_so3(kind, size, radius):
    rots = global_search.rotation_hypotheses(kind)
    assert rots.shape == (size, 3, 3)
    np.testing.assert_allclose(rots[0], np.eye(3), atol=1e-12)
    np.testing.assert_allclose(rots @ np.swapaxes(rots, 1, 2), np.broadcast_to(np.eye(3), rots.shape), atol=1e-12)
    assert np.all(np.linalg.det(rots) > 0.999)
    # every one of 20,000 random rotations lies within the covering radius of some hypothesis
    probe = Rotation.random(20000, random_state=0).as_quat()
    hyp = Rotation.from_matrix(rots).as_quat()
    nearest = 2 * np.degrees(np.arccos(np.clip(np.abs(probe @ hyp.T).max(axis=1), -1, 1)))
    assert nearest.max() < radius


@pytest.mark.slow  # compiles both register paths (~25 s)
def test_register_from_identity_equals_register():
    """One hypothesis at the identity is register itself; H hypotheses equal H separate register calls on
    the source moved by each start (rigid motions leave neighbour sets and PPF unchanged)."""
    rng = np.random.default_rng(0)
    params = rpmnet_jax.init_params(jax.random.PRNGKey(0))
    pts, nrm = asymmetric_shape(1, 600)
    src = np.concatenate([pts[:300], nrm[:300]], 1)[None].astype(np.float32)
    ref = np.concatenate([pts[300:], nrm[300:]], 1)[None].astype(np.float32)
    plain = registration.register(params, src, ref, num_iters=2)
    one = registration.register_from(params, src, ref, np.eye(3, 4, dtype=np.float32)[None], num_iters=2)
    np.testing.assert_allclose(one.transforms, plain.transforms, atol=1e-6)
    starts = global_search.initial_transforms("octahedral")[:3]
    many = registration.register_from(params, src, ref, starts, num_iters=1)
    for h, start in enumerate(starts):
        moved = src.copy()
        moved[0, :, :3] = src[0, :, :3] @ start[:, :3].T
        moved[0, :, 3:] = src[0, :, 3:] @ start[:, :3].T
        single = registration.register(params, moved, ref, num_iters=1).transform[0]  # maps the moved source
        composed = np.concatenate([single[:, :3] @ start[:, :3], single[:, 3:]], 1)  # ... so compose the start
        np.testing.assert_allclose(many.transforms[0, h], composed, atol=2e-4)
    del rng


@pytest.mark.skipif(not loading.has_default(), reason="no shipped model in this checkout")
@pytest.mark.parametrize("degrees,axis", [(100.0, [0.3, 0.8, 0.5]), (178.0, [1.0, -0.2, 0.4])])
def test_global_init_recovers_large_rotations(degrees, axis):
    pts, nrm = asymmetric_shape(2, 4000)
    rot = rotation_about(axis, degrees)
    trans = np.array([0.3, -0.2, 0.1])
    src, src_n = pts[:3000], nrm[:3000]
    ref, ref_n = pts[1000:] @ rot.T + trans, nrm[1000:] @ rot.T  # rot maps src onto ref
    network_only = rpmnet_jax.GlobalOptions(classical=0)  # the network's rotation hypotheses alone
    result = rpmnet_jax.align(src, ref, src_n, ref_n, init="global", global_options=network_only)
    assert rotation_error_deg(result.transform[:3, :3], rot) < 1.0
    assert np.linalg.norm(result.transform[:3, 3] - trans) < 0.02
    assert "global" in result.stages and result.fitness > 0.6
    # the identity start, refined first, may slide to the same answer (one distinct answer then, the earlier
    # start's name): the screen's own starts, each refined as align refines them, must reach it too
    inputs = prepare.for_alignment(src, ref, src_n, ref_n, num_points=1024, sampling="random", seed=0,
                                   reestimate_normals=False, centering="separate", icp=True, dense_points=5000,
                                   max_correspondence_distance=None, relative_distance=0.05)
    screened = global_search.screen_hypotheses(loading.load_default_params(), inputs.pair, inputs.dense,
                                               rpmnet_jax.RPMNetConfig(), network_only, inputs.max_distance_unit, 0)
    refined = candidates.refine_starts(screened, inputs.dense, inputs.max_distance_unit, "icp",
                                       rpmnet_jax.RefineOptions())
    best = max(refined, key=lambda c: c.score)
    assert rotation_error_deg(inputs.pair.to_callers_units(best.transform[:3])[:3, :3], rot) < 1.0
    assert best.converged  # from a screened start the refinement ends on its tolerance
    with_classical = rpmnet_jax.align(src, ref, src_n, ref_n, init="global")
    assert rotation_error_deg(with_classical.transform[:3, :3], rot) < 1.0


@pytest.mark.skipif(not loading.has_default(), reason="no shipped model in this checkout")
def test_the_starts_run_a_few_a_call_as_all_at_once(monkeypatch):
    """The rotation starts through the network ``HYPOTHESES_A_CALL`` at a time (a site's placement holds a fraction of
    the activations): the same screened starts, iterates and confidences as one call of all of them, but for
    float32 sums in other batch shapes."""
    pts, nrm = asymmetric_shape(3, 3000)
    rot = rotation_about([0.2, -0.5, 0.8], 120.0)
    inputs = prepare.for_alignment(pts[:2000], pts[800:] @ rot.T, nrm[:2000], nrm[800:] @ rot.T, num_points=512,
                                   sampling="random", seed=0, reestimate_normals=False, centering="separate",
                                   icp=True, dense_points=3000, max_correspondence_distance=None,
                                   relative_distance=0.05)
    opts = rpmnet_jax.GlobalOptions(classical=0, top_k=24)  # every start screened, ranked

    def screened(per_call):
        monkeypatch.setattr(global_search, "HYPOTHESES_A_CALL", per_call)
        return global_search.screen_hypotheses(loading.load_default_params(), inputs.pair, inputs.dense,
                                               rpmnet_jax.RPMNetConfig(), opts, inputs.max_distance_unit, 0)

    per_call = global_search.HYPOTHESES_A_CALL
    assert per_call < 24
    whole, parts = screened(24), screened(per_call)
    assert len(whole) == len(parts) == 24
    for a in whole:  # each start's twin: the nearest iterates (the ranking may swap near ties)
        b = min(parts, key=lambda s: np.abs(s.network_transforms - a.network_transforms).max())
        np.testing.assert_allclose(b.network_transforms, a.network_transforms, rtol=0, atol=1e-4)  # float32 sums in
        # other batch shapes: measured 1.3e-5 (a rotation's entries: 1e-4 is 0.006 deg)
        np.testing.assert_allclose(b.confidence, a.confidence, rtol=0, atol=1e-4)  # in [0, 1]
    assert len({id(min(parts, key=lambda s: np.abs(s.network_transforms - a.network_transforms).max()))
                for a in whole}) == 24  # one twin each
