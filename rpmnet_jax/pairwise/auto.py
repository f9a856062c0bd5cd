"""``init="auto"``'s whole decision: on dense clouds the classical answer (:func:`keeps_classical`); else
(:func:`runs`) after the classical candidates, whether the network runs from the identity; after it, whether the
network's global search runs.

Its bars, every one of them, are :class:`~rpmnet_jax.pairwise.options.GlobalOptions` fields or named here:
``network_fitness`` (0.6: a best classical answer below it is weak), ``network_doubt`` (0.15: a weak answer stands
without the network below this ``p_wrong``), :data:`DOUBT_FLOOR` (0.45: below this fitness it never stands),
``auto_fitness`` (0.6: below it the global search runs unless two independent starts agree) and
``candidates.AMBIGUITY_SHARE`` (an ambiguous answer never stands). What they were chosen on and what they do on
held-out data: ``docs/pipeline.md`` (step 2) and ``docs/results.md`` ("When the network runs").
"""

from __future__ import annotations

from rpmnet_jax.pairwise import candidates as candidates_lib

DOUBT_FLOOR = 0.45  # below this fitness a weak answer runs the network whatever its doubt (docs/pipeline.md)


def keeps_classical(found: list, dense: bool, opts) -> bool:
    """On ``dense`` clouds (``starts.dense``: scans, whose hypotheses come from a voxel grid of the whole clouds) the
    best classical answer is kept, whatever its doubt, when there is one and ``opts.network_on_dense`` is off: on
    the dense tuning pairs the network's fallback lost more answers than it rescued (docs/pipeline.md, step 2)."""
    return bool(found) and dense and not opts.network_on_dense


def weak(found: list, opts) -> bool:
    """The best refined classical candidate (by selection score) is missing, ambiguous (a flip scores close to
    it: the network's start may tell them apart) or below ``opts.network_fitness`` (always at 1)."""
    if not found or opts.network_fitness >= 1.0:
        return True
    ranked = candidates_lib.distinct(found)
    return ranked[0].score[1] < opts.network_fitness or candidates_lib.is_ambiguous(ranked)


def may_stand(opts) -> bool:
    """Whether a weak classical answer may stand at all (``network_doubt`` 0 or ``network_fitness`` 1: never)."""
    return 0 < opts.network_doubt and opts.network_fitness < 1.0


def stands(answer, opts) -> bool:
    """Whether a weak classical ``answer`` (an :class:`~rpmnet_jax.pairwise.alignment.Alignment`) stands without
    the network: not ambiguous, its fitness at least :data:`DOUBT_FLOOR` and its ``p_wrong`` below
    ``opts.network_doubt``."""
    return (may_stand(opts) and not answer.ambiguous and answer.fitness >= DOUBT_FLOOR
            and answer.p_wrong < opts.network_doubt)


def confirmed(found: list) -> bool:
    """The best distinct candidate is reached from a classical start and from the network's local start alone
    (within ``AMBIGUITY_DEG``) and nothing else scores close to it: two independent starts agree."""
    ranked = candidates_lib.distinct(found)
    if candidates_lib.is_ambiguous(ranked):
        return False
    inits = candidates_lib.support(ranked[:1], found)[0]
    return "classical" in inits and "local" in inits


def runs(stage: str, found: list, opts) -> bool:
    """Whether ``init="auto"`` runs ``stage`` given the refined candidates ``found`` so far (a weak classical answer
    that :func:`stands` has ended the search before): ``"network"`` when the classical candidates are
    :func:`weak`; ``"global"`` when no candidate reaches ``opts.auto_fitness`` (always at 1) and the best one is not
    :func:`confirmed`."""
    if stage == "network":
        return weak(found, opts)
    if stage == "global":
        best = max((c.score[1] for c in found), default=0.0)
        return best < opts.auto_fitness and (opts.auto_fitness >= 1.0 or not confirmed(found))
    raise ValueError(f"unknown stage {stage!r}")
