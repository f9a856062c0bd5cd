"""Step 4 of :func:`rpmnet_jax.align_scans`: the scans the pose graph left unplaced, registered onto the merged
placed scans by :func:`rpmnet_jax.align` with ``init="global"`` (rotation hypotheses covering every orientation).

They come in groups (:class:`Group`): the scans that the pair edges join among themselves, with their poses
relative to one another from their own robust pose graph, and single scans. A group moves as one: a member
registered onto the merged scans places the whole group, and a group of several scans is placed only where none
of its members lies in the free space of a placed scan it overlaps (on a site the streets look alike; a group
spans more of one than a single scan does, so a look-alike street rarely takes all of it). In a campaign a
scan is registered onto its best-scored placed partners only: local work, and fewer look-alike streets to land on."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from rpmnet_jax.geometry import normals as normals_lib, sampling
from rpmnet_jax.classical import scoring
from rpmnet_jax.multiway import edge_graph
from rpmnet_jax.pair_edges import edges as edges_lib
from rpmnet_jax.ops import se3
from rpmnet_jax.pairwise import alignment
from rpmnet_jax.pose_graphs import pose_graph


class Group(NamedTuple):
    """Unplaced scans that move as one."""

    members: tuple  # scan indices, in the order their placement is tried
    poses: np.ndarray  # (k, 4, 4): each member → the group's frame
    edges: tuple = ()  # the pair edges that join them (kept by their pose graph)


def unplaced_groups(num_scans: int, pair_edges, poses: np.ndarray, noise: tuple, seed: int, weigh: bool,
                    weak_bar: float = 0.0) -> list:
    """The scans NaN in ``poses (S, 4, 4)`` as :class:`Group` s: each connected part of the ``pair_edges`` among
    them (those with a balanced fitness of at least ``weak_bar``: a campaign's weak edges join no group,
    :data:`~rpmnet_jax.multiway.edge_graph.WEAK_LINK`) with its own robust pose graph
    (:func:`~rpmnet_jax.multiway.edge_graph.solve` anchored at its first scan, ``noise`` as there, the edges ranked
    by their doubt weights when ``weigh``), its members those that graph placed; then every scan left, a group of
    one. Largest first, ties by their first scan."""
    unplaced = ~np.isfinite(poses[:, 0, 0])
    among = [e for e in pair_edges if unplaced[e.source] and unplaced[e.target] and e.balanced_fitness >= weak_bar]
    labels = pose_graph.components(num_scans, [(e.source, e.target) for e in among])
    groups, grouped = [], np.zeros(num_scans, bool)
    for label in np.unique(labels[unplaced]):
        members = np.flatnonzero((labels == label) & unplaced)
        if len(members) < 2:
            continue
        part = [e for e in among if labels[e.source] == label]
        at, kept, _ = edge_graph.solve(num_scans, part, int(members[0]), noise, seed,
                                       edge_graph.doubt_weights(part) if weigh else None)
        placed = [int(m) for m in members if np.isfinite(at[m, 0, 0])]
        if len(placed) > 1:
            groups.append(Group(tuple(placed), at[placed], tuple(kept)))
            grouped[placed] = True
    groups.sort(key=lambda g: (-len(g.members), g.members[0]))
    return groups + [Group((int(s),), np.eye(4)[None]) for s in np.flatnonzero(unplaced & ~grouped)]


def group_ends(group: Group, sensors, reach: float) -> list:
    """The members of ``group`` at its ends: those whose fellow members with sensors within ``reach`` (``sensors``:
    ``(3,)`` each, in its scan's coordinates, at the group's poses) all lie on one side of it (none does, or every
    one lies within a right angle of their mean direction), in the group's order; all its members where none is
    (a loop). A street's group meets the placed streets at its ends."""
    at = np.array([pose[:3, :3] @ sensors[m] + pose[:3, 3] for m, pose in zip(group.members, group.poses)])
    ends = []
    for k, member in enumerate(group.members):
        offsets = at - at[k]
        distance = np.linalg.norm(offsets, axis=1)
        near = offsets[(distance > 0) & (distance <= reach)]
        if len(near) == 0 or (near @ near.mean(axis=0)).min() > 0:
            ends.append(member)
    return ends or list(group.members)


def voted_frame(poses: np.ndarray, group: Group, pair_edges, agree_deg: float, agree_distance: float):
    """Where the pair edges between ``group``'s members and placed scans (finite in ``poses (S, 4, 4)``) put the
    group: ``(frame (4, 4): the group's frame → the placed scans', the edges that agree on it)``, the frame that
    the most distinct members and distinct placed scans agree on (each edge's frame within ``agree_deg`` and, at the
    members' mean position, ``agree_distance`` of it), at least two of each; None where no two edges agree. One
    wrong edge puts a group on a look-alike street; two edges from different scans that agree rarely do."""
    at = {m: k for k, m in enumerate(group.members)}
    centre = group.poses[:, :3, 3].mean(axis=0)
    votes = []
    for e in pair_edges:
        if e.source in at and np.isfinite(poses[e.target, 0, 0]):
            m, o, to_placed = e.source, e.target, e.transform
        elif e.target in at and np.isfinite(poses[e.source, 0, 0]):
            m, o, to_placed = e.target, e.source, np.linalg.inv(e.transform)
        else:
            continue
        votes.append((m, o, poses[o] @ to_placed @ np.linalg.inv(group.poses[at[m]]), e))
    best, best_support, need = None, (0, 0.0), (min(2, len(group.members)), 2)
    for m, o, frame, _ in votes:
        agree = [v for v in votes if _same_frame(frame, v[2], centre, agree_deg, agree_distance)]
        members, placed = len({v[0] for v in agree}), len({v[1] for v in agree})
        support = (min(members, placed), sum(v[3].balanced_fitness for v in agree))
        if members >= need[0] and placed >= need[1] and support > best_support:
            best, best_support = (frame, [v[3] for v in agree]), support
    return best


def _same_frame(a: np.ndarray, b: np.ndarray, centre: np.ndarray, max_deg: float, max_distance: float) -> bool:
    """Whether frames ``a`` and ``b (4, 4)`` differ by at most ``max_deg`` and move ``centre (3,)`` by at most
    ``max_distance``."""
    moved = np.linalg.norm((a[:3, :3] - b[:3, :3]) @ centre + a[:3, 3] - b[:3, 3])
    return bool(se3.rotation_angle_deg(a[:3, :3].T @ b[:3, :3]) <= max_deg and moved <= max_distance)


def merged(scans, poses, placed, voxel: float) -> tuple:
    """``(points (M, 3), normals (M, 3))``: the ``placed`` scans at ``poses``, one cloud downsampled at ``voxel``."""
    points = np.concatenate([se3.apply(poses[s], scans[s].points) for s in placed])
    points, _ = sampling.voxel_downsample(points, None, voxel)
    return points, normals_lib.estimate_normals(points)


def place_remaining(scans, poses, groups, params, cfg, voxel, max_dist, accept, seed, tick, visible=None,
                    partners=None, max_tries=None, place_doubtful=True, joined=None):
    """Places the ``groups`` (:class:`Group` s of the scans NaN in ``poses (S, 4, 4)``), in order: each member in
    turn registered onto the merged placed scans until one's answer passes ``accept(fitness, median plane
    residual, balanced fitness)`` and, for a group of several scans, ``visible(edge) -> bool`` (the pair edges'
    free-space check) on every member's edge to the placed scans it may overlap (bounding spheres within
    ``max_dist``); the group then placed, the scans merged again (``tick(placed, scans)``) and the groups left
    tried again from the first. A single scan whose edge to a placed scan fails ``visible`` is placed and named (a
    scan registered onto the merged scans can land on a street elsewhere that looks alike). With
    ``partners(scan) -> [scan, ...]`` (a levelled campaign's best-scored partners of a scan) a member is registered
    onto its placed partners only (onto the placed scans ``joined[scan]`` when any: those its pair edges join it to,
    measured to overlap it), its group's edges measured to those, and every pending group is tried once a
    round from at most ``max_tries`` of its members that have placed partners (local work: no merge of every
    placed scan, no restart after each placement). With ``place_doubtful=False`` no answer that fails
    ``visible`` or is ``likely_wrong`` places a scan (the next member is tried; a group none places stays
    pending). Returns (poses, the placed scans' edges to the scans placed before them that they may overlap (the
    partners) and their groups' edges, scans still pending, placed scans whose ``align`` answer was
    ``likely_wrong`` or failed ``visible``)."""
    placed = [s for s in range(len(scans)) if np.isfinite(poses[s, 0, 0])]
    pending = list(groups)
    edges, doubtful = [], []
    spheres = [bounding_sphere(s.points) for s in scans]
    grew = True
    while pending and grew:
        grew = False
        if partners is None:
            model = merged(scans, poses, placed, voxel)

            def model_of(s, model=model, others=tuple(placed)):
                return (*model, others)
        else:
            is_placed = np.isfinite(poses[:, 0, 0])

            def model_of(s, is_placed=is_placed):
                near = ([o for o in (joined or {}).get(s, ()) if is_placed[o]]
                        or [o for o in partners(s) if is_placed[o]])
                return (*merged(scans, poses, near, voxel), near) if near else None
        for group in list(pending):
            answer = _place_group(scans, poses, group, model_of, params, cfg, max_dist, accept, seed, visible,
                                  spheres, max_tries, place_doubtful)
            if answer is None:
                continue
            found, seen_through, likely_wrong = answer
            doubtful += list(group.members) if likely_wrong or seen_through else []
            edges += found + list(group.edges)
            placed += list(group.members)
            pending.remove(group)
            tick(len(placed), len(scans))
            grew = True
            if partners is None:
                break  # the model grew: merge again before the next group
    return poses, edges, [s for g in pending for s in g.members], doubtful


def bounding_sphere(points: np.ndarray) -> tuple:
    """``(centre (3,), radius)``: the centroid of ``points (N, 3)`` and the largest distance from it."""
    centre = points.mean(axis=0)
    return centre, float(np.sqrt(((points - centre) ** 2).sum(axis=1).max()))


def _may_overlap(spheres, a: int, pose_a, b: int, pose_b, max_dist: float) -> bool:
    """Whether scans ``a`` and ``b`` at these poses come within ``max_dist`` (their bounding spheres do)."""
    (ca, ra), (cb, rb) = spheres[a], spheres[b]
    gap = np.linalg.norm(pose_a[:3, :3] @ ca + pose_a[:3, 3] - pose_b[:3, :3] @ cb - pose_b[:3, 3])
    return bool(gap <= ra + rb + max_dist)


def _place_group(scans, poses, group, model_of, params, cfg, max_dist, accept, seed, visible, spheres,
                 max_tries=None, place_doubtful=True):
    """The first member of ``group`` whose registration onto its model places the group (see
    :func:`place_remaining`; ``model_of(scan) -> (points, normals, the placed scans in it)`` or None): ``poses`` of
    its members set, ``(edges to those placed scans it may overlap (``spheres``: each scan's bounding sphere; no
    edge where they keep apart: its fitness would be 0), whether one failed visible, align's likely_wrong)``; None
    when none does (``poses`` untouched); at most ``max_tries`` members registered (None: every one)."""
    tries = 0
    for k, s in enumerate(group.members):
        local = model_of(s) if max_tries is None or tries < max_tries else None
        if local is None:
            continue
        tries += 1
        model, model_normals, others = local
        a = alignment.align(scans[s].points, model, scans[s].normals, model_normals, params=params, cfg=cfg,
                            init="global", max_correspondence_distance=max_dist, seed=seed)
        residuals = scoring.plane_fit(scans[s].points, model, model_normals, a.transform, a.correspondences).residuals
        if not accept(a.fitness, np.median(np.abs(residuals)) if len(residuals) else np.inf,
                      scoring.balanced_fitness(scans[s].normals, a.correspondences[:, 0])):
            continue
        frame = a.transform @ np.linalg.inv(group.poses[k])  # the group's frame → the placed scans' frame
        at = {m: frame @ p for m, p in zip(group.members, group.poses)}
        found = [edges_lib.measure(scans, m, o, np.linalg.inv(poses[o]) @ at[m], max_dist, "global")
                 for m in group.members for o in others if _may_overlap(spheres, m, at[m], o, poses[o], max_dist)]
        seen_through = visible is not None and not all(visible(e) for e in found)
        if (seen_through and len(group.members) > 1) or (not place_doubtful and (seen_through or a.likely_wrong)):
            continue  # where its scans could not have been, or doubted: another member may place it right
        for m in group.members:
            poses[m] = at[m]
        return found, seen_through, a.likely_wrong
    return None
