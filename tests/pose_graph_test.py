"""The robust pose graph: flipped edges rejected, spanning trees and components, singular and invalid
information matrices, ``max_rounds=0``."""

import itertools

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from conftest import random_pose, rotation_error_deg
from rpmnet_jax.pose_graphs import pose_graph


def _graph(rng, num_nodes=7, noise_deg=0.05, noise_t=1e-4):
    """Random poses ``(S, 4, 4)`` (node 0 at the identity), every pair as an edge with a measured transform
    jittered by ``noise_deg`` and ``noise_t`` per axis, and the matching diagonal information matrices (the
    identity for exact edges)."""
    poses = np.stack([np.eye(4)] + [random_pose(rng) for _ in range(num_nodes - 1)])
    pairs = list(itertools.combinations(range(num_nodes), 2))
    transforms = []
    for i, j in pairs:
        jitter = np.eye(4)
        jitter[:3, :3] = Rotation.from_rotvec(np.radians(noise_deg) * rng.normal(size=3)).as_matrix()
        jitter[:3, 3] = noise_t * rng.normal(size=3)
        transforms.append(np.linalg.inv(poses[j]) @ poses[i] @ jitter)
    info = np.diag([np.radians(noise_deg) ** -2] * 3 + [noise_t ** -2] * 3) if noise_deg and noise_t else np.eye(6)
    return poses, pairs, np.stack(transforms), np.broadcast_to(info, (len(pairs), 6, 6))


def _flip(rng, transforms, edges):
    """``transforms`` with each of ``edges`` turned by 150–180° about a random axis (a symmetric wrong answer)."""
    transforms = transforms.copy()
    for e in edges:
        axis = rng.normal(size=3)
        flip = np.eye(4)
        flip[:3, :3] = Rotation.from_rotvec(np.radians(rng.uniform(150, 180)) * axis / np.linalg.norm(axis)).as_matrix()
        transforms[e] = transforms[e] @ flip
    return transforms


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_robust_pose_graph_rejects_flipped_edges(seed):
    """5 of 21 edges flipped by 150–180° about random axes (as a symmetric wrong answer is): exactly those are
    rejected, whatever their weights say, and the poses are the truth's; least squares is pulled away."""
    rng = np.random.default_rng(seed)
    poses, pairs, transforms, info = _graph(rng)
    wrong = rng.choice(len(pairs), 5, replace=False)
    transforms = _flip(rng, transforms, wrong)
    weights = np.ones(len(pairs))
    weights[wrong] = 2.0  # the wrong edges look best: the maximum-weight tree holds them
    sol = pose_graph.optimize(len(poses), pairs, transforms, info, 0, weights=weights)
    assert sorted(np.nonzero(~sol.inlier)[0]) == sorted(wrong)
    for got, want in zip(sol.poses, poses):
        # 4× the 0.05° per-axis edge noise; a node's pose averages 6 edges, so its error is well below that
        assert rotation_error_deg(got[:3, :3], want[:3, :3]) < 0.2
        assert np.linalg.norm(got[:3, 3] - want[:3, 3]) < 1e-3  # 10× the 1e-4 per-axis translation noise
    plain = pose_graph.optimize(len(poses), pairs, transforms, info, 0, weights=weights, robust=False)
    assert plain.inlier.all()
    assert max(rotation_error_deg(g[:3, :3], w[:3, :3]) for g, w in zip(plain.poses, poses)) > 5


def test_spanning_tree_and_components():
    rng = np.random.default_rng(3)
    poses, pairs, transforms, info = _graph(rng, num_nodes=5, noise_deg=1e-7, noise_t=1e-9)
    keep = [k for k, (i, j) in enumerate(pairs) if j == i + 1 and j != 4]  # a chain 0-1-2-3; node 4 apart
    tree = pose_graph.spanning_tree_poses(5, [pairs[k] for k in keep], transforms[keep], np.ones(len(keep)), 0)
    np.testing.assert_allclose(tree[:4], poses[:4], atol=1e-9)  # 3 composed edges of 1e-7° / 1e-9 noise
    assert np.all(np.isnan(tree[4]))
    np.testing.assert_array_equal(pose_graph.component(5, [pairs[k] for k in keep], 2), [1, 1, 1, 1, 0])
    sol = pose_graph.optimize(5, [pairs[k] for k in keep], transforms[keep], info[keep], 0)  # a tree: plain LM
    assert sol.inlier.all() and np.all(np.isnan(sol.poses[4]))
    # LM's own stopping tolerance on the whitened errors, not the edge noise, sets this one
    np.testing.assert_allclose(sol.poses[:4], poses[:4], atol=1e-7)


def _planar_information(rng, normal, sigma=1e-3):
    """``(6, 6)`` point-to-plane information ``JᵀJ / σ²`` of a flat patch with unit ``normal``: rank 3 (the
    rotations about two in-plane axes and the translation along the normal); sliding in the plane and turning
    about its normal are free. Its three zero eigenvalues come out of the product as round-off of either sign."""
    u = np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    p = rng.uniform(-1, 1, size=(200, 1)) * u + rng.uniform(-1, 1, size=(200, 1)) * np.cross(normal, u) + 0.3 * normal
    m = np.broadcast_to(normal, p.shape)
    jac = np.concatenate([np.cross(p, m), m], axis=1)
    return jac.T @ jac / sigma ** 2


@pytest.mark.parametrize("noise_deg,noise_t", [(0.0, 0.0), (0.05, 1e-4)], ids=["exact", "noisy"])
def test_a_singular_information_matrix_is_usable(noise_deg, noise_t):
    """Every edge with a planar scan's rank-3 information (GTSAM's Gaussian noise model wants a Cholesky factor):
    the graph is optimised and the poses are finite rigid transforms; with exact edges, the truth (the free
    directions have nothing to pull them off). With noise they may drift along those directions: the rotation of
    every other node about the anchor's plane normal changes no edge of it."""
    rng = np.random.default_rng(4)
    poses, pairs, transforms, _ = _graph(rng, num_nodes=4, noise_deg=noise_deg, noise_t=noise_t)
    normal = rng.normal(size=3)
    information = _planar_information(rng, normal / np.linalg.norm(normal))
    assert np.linalg.matrix_rank(information) == 3
    sol = pose_graph.optimize(4, pairs, transforms, np.broadcast_to(information, (len(pairs), 6, 6)), 0)
    assert np.all(np.isfinite(sol.poses))
    for got in sol.poses:
        np.testing.assert_allclose(got[:3, :3] @ got[:3, :3].T, np.eye(3), atol=1e-9)  # float64 round-off
    if noise_deg == 0.0:
        assert sol.inlier.all()
        for got, want in zip(sol.poses, poses):
            # exact edges: round-off of the composed float64 transforms only
            assert rotation_error_deg(got[:3, :3], want[:3, :3]) < 1e-6
            assert np.linalg.norm(got[:3, 3] - want[:3, 3]) < 1e-8


def test_max_rounds_zero_keeps_every_edge():
    """``max_rounds=0``: the robust (Cauchy) LM's answer with no rejection round, every edge kept; with the
    default rounds the flipped edge is rejected."""
    rng = np.random.default_rng(5)
    poses, pairs, transforms, info = _graph(rng, num_nodes=5)
    transforms = _flip(rng, transforms, [3])
    sol = pose_graph.optimize(5, pairs, transforms, info, 0, max_rounds=0)
    assert sol.inlier.all() and np.all(np.isfinite(sol.poses))
    default = pose_graph.optimize(5, pairs, transforms, info, 0)
    assert np.flatnonzero(~default.inlier).tolist() == [3]


@pytest.mark.parametrize("information", [np.zeros((6, 6)), np.diag([1.0, 1.0, 1.0, 1.0, 1.0, -1.0])],
                         ids=["zero", "indefinite"])
def test_an_invalid_information_matrix_is_a_value_error(information):
    rng = np.random.default_rng(6)
    _, pairs, transforms, info = _graph(rng, num_nodes=3)
    info = info.copy()
    info[1] = information
    with pytest.raises(ValueError, match="positive semi-definite"):
        pose_graph.optimize(3, pairs, transforms, info, 0)


def test_triangle_support_counts_the_triangles_that_agree():
    rng = np.random.default_rng(3)
    poses = np.stack([np.eye(4)] + [random_pose(rng) for _ in range(4)])
    pairs = [(0, 1), (1, 2), (0, 2), (2, 3), (1, 3), (3, 4)]
    transforms = np.stack([np.linalg.inv(poses[j]) @ poses[i] for i, j in pairs])
    information = np.tile(np.eye(6) * 1e4, (len(pairs), 1, 1))
    support = pose_graph.triangle_support(pairs, transforms, information, threshold=1.0)
    # (1, 2) closes two triangles (with 0 and with 3); (3, 4) none
    np.testing.assert_array_equal(support, [1, 2, 1, 1, 1, 0])
    wrong = transforms.copy()
    wrong[3] = transforms[3] @ np.diag([-1.0, -1.0, 1.0, 1.0])  # (2, 3) half turned
    support = pose_graph.triangle_support(pairs, wrong, information, threshold=1.0)
    np.testing.assert_array_equal(support, [1, 1, 1, 0, 0, 0])  # the triangle 1-2-3 no longer agrees
