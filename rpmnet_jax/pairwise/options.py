"""The knobs of :func:`rpmnet_jax.align` beyond the common ones, as small frozen options objects (as Open3D's
``ICPConvergenceCriteria``): :class:`RefineOptions` for the ICP refinement, :class:`GlobalOptions` for the
global search. Each checks its values when it is made; :func:`check` checks the plain keywords of ``align``.
"""

from __future__ import annotations

import dataclasses

INITS = ("auto", "local", "global", "classical")
REFINES = ("icp", "none")
HYPOTHESIS_SETS = {"icosahedral": "I", "octahedral": "O"}  # rotation groups of the global search (SciPy names)


@dataclasses.dataclass(frozen=True)
class RefineOptions:
    """Robust point-to-plane ICP of every candidate (``refine="icp"``).

    ``points``: source points sampled from the caller's cloud (the reference: up to ``20 × points``). ``scales``
    (gates as multiples of the correspondence distance, coarse to fine), ``max_iterations`` (per stage) and
    ``tolerance`` (update size that ends a stage): ``None`` keeps
    :func:`rpmnet_jax.geometry.icp.point_to_plane_icp`'s default.
    """

    points: int = 5000
    scales: tuple[float, ...] | None = None
    max_iterations: int | None = None
    tolerance: float | None = None

    def __post_init__(self):
        if self.points < 3:
            raise ValueError(f"RefineOptions.points must be >= 3, got {self.points}")
        if self.scales is not None:
            object.__setattr__(self, "scales", tuple(float(s) for s in self.scales))
            if not self.scales or min(self.scales) <= 0:
                raise ValueError(f"RefineOptions.scales must be positive numbers, got {self.scales}")
        if self.max_iterations is not None and self.max_iterations < 1:
            raise ValueError(f"RefineOptions.max_iterations must be >= 1, got {self.max_iterations}")
        if self.tolerance is not None and not self.tolerance > 0:
            raise ValueError(f"RefineOptions.tolerance must be > 0, got {self.tolerance}")

    def icp_kwargs(self) -> dict:
        """The keywords for :func:`rpmnet_jax.geometry.icp.point_to_plane_icp` that are set."""
        fields = ("scales", "max_iterations", "tolerance")
        return {f: getattr(self, f) for f in fields if getattr(self, f) is not None}


@dataclasses.dataclass(frozen=True)
class GlobalOptions:
    """The orientation-free starts of ``init="auto"`` and ``"global"``.

    ``classical``: how many distinct FPFH + RANSAC hypotheses (:mod:`rpmnet_jax.geometry.feature_ransac`,
    rotation-invariant, at least 45° apart) join the candidates of ``auto`` and ``global`` (0: none).
    ``auto`` refines them first and runs the network from the identity only when the best one's fitness is
    below ``network_fitness`` (always at 1) or it is ambiguous (a flip scores close to it).
    The network's global search (``init="global"``, or ``"auto"`` when no candidate reaches a fitness of
    ``auto_fitness``): ``hypotheses``, ``octahedral`` (24) or ``icosahedral`` (60) rotation starts, screened
    with ``iters`` network iterations on ``points`` per cloud and a short ICP on ``polish_points`` source
    points; the ``top_k`` best are refined.
    """

    hypotheses: str = "octahedral"
    top_k: int = 3
    points: int = 256
    iters: int = 2
    polish_points: int = 1000
    auto_fitness: float = 0.6
    classical: int = 4
    network_fitness: float = 0.6

    def __post_init__(self):
        if self.hypotheses not in HYPOTHESIS_SETS:
            raise ValueError(f"GlobalOptions.hypotheses must be one of {sorted(HYPOTHESIS_SETS)}, "
                             f"got {self.hypotheses!r}")
        if self.top_k < 1:
            raise ValueError(f"GlobalOptions.top_k must be >= 1, got {self.top_k}")
        if self.points < 3 or self.polish_points < 3:
            raise ValueError(f"GlobalOptions.points and polish_points must be >= 3, got {self.points}, "
                             f"{self.polish_points}")
        if self.iters < 1:
            raise ValueError(f"GlobalOptions.iters must be >= 1, got {self.iters}")
        if not 0.0 <= self.auto_fitness <= 1.0:
            raise ValueError(f"GlobalOptions.auto_fitness must be in [0, 1], got {self.auto_fitness}")
        if not 0.0 <= self.network_fitness <= 1.0:
            raise ValueError(f"GlobalOptions.network_fitness must be in [0, 1], got {self.network_fitness}")
        if self.classical < 0:
            raise ValueError(f"GlobalOptions.classical must be >= 0, got {self.classical}")


def check(init: str, refine: str, num_iters: int, max_correspondence_distance: float | None,
          refine_options, global_options) -> None:
    """Raises ``ValueError`` for a bad plain keyword of :func:`rpmnet_jax.align` or an options object of the
    wrong type (the options objects check their own values)."""
    if init not in INITS:
        raise ValueError(f"init must be one of {INITS}, got {init!r}")
    if refine not in REFINES:
        raise ValueError(f"refine must be one of {REFINES}, got {refine!r}")
    if num_iters < 1:
        raise ValueError(f"num_iters must be >= 1, got {num_iters}")
    if max_correspondence_distance is not None and not max_correspondence_distance > 0:
        raise ValueError(f"max_correspondence_distance must be > 0, got {max_correspondence_distance}")
    if not isinstance(refine_options, RefineOptions):
        raise ValueError(f"refine_options must be a RefineOptions, got {type(refine_options).__name__}")
    if not isinstance(global_options, GlobalOptions):
        raise ValueError(f"global_options must be a GlobalOptions, got {type(global_options).__name__}")
    if init == "classical" and global_options.classical < 1:
        raise ValueError("init='classical' needs GlobalOptions.classical >= 1 (the hypotheses it refines)")
