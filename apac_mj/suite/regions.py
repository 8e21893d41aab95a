"""The generalization split measured: reachable area and grid targets per region.

The test region is the band ``y >= region.test_y_min`` of the plane (see
:class:`~apac_mj.suite.task_spec.Region`). These helpers measure what that
band holds at a task's initial link lengths: the fraction of the reachable
area (by rasterizing the motion function over a dense angle grid) and how many
of the paper's test targets (:func:`~apac_mj.kinematics.angle_grid`) fall in it.
"""
from __future__ import annotations

import dataclasses
import functools

import numpy as np

from apac_mj.kinematics import angle_grid, motion_function
from apac_mj.suite.task_spec import TaskSpec


@dataclasses.dataclass(frozen=True)
class RegionStats:
    """What the test region holds at one set of link lengths."""

    test_y_min: float
    link_lengths: tuple[float, float]
    #: Fraction of the reachable area (within the plane) with y >= test_y_min.
    test_area_fraction: float
    #: angle_grid() targets in the test region, and in all.
    grid_targets_in_test: int
    grid_targets: int


def reachable_cells(spec: TaskSpec, n_angles: int = 1200, cell: float = 0.05) -> np.ndarray:
    """Centres ``(k, 2)`` of the ``cell``-sized plane cells the end-effector can reach.

    Rasterizes :func:`motion_function` over an ``n_angles x n_angles`` grid of
    both joint ranges; with the defaults neighbouring samples lie < ``cell`` apart
    for links up to ~15 cm, so the reachable set has no holes.
    """
    return _reachable_cells(tuple(spec.link_lengths), tuple(spec.origin), tuple(spec.plane_size), n_angles, cell)


@functools.lru_cache(maxsize=16)
def _reachable_cells(lengths: tuple, origin: tuple, plane_size: tuple, n_angles: int, cell: float) -> np.ndarray:
    angles = np.linspace(0.0, 180.0, n_angles)
    alpha, beta = np.meshgrid(angles, angles, indexing="ij")
    end, _ = motion_function(alpha.ravel(), beta.ravel(), *lengths, origin)
    w, h = plane_size
    on_plane = (end[:, 0] >= 0) & (end[:, 0] <= w) & (end[:, 1] >= 0) & (end[:, 1] <= h)
    shape = (int(np.ceil(w / cell)) + 1, int(np.ceil(h / cell)) + 1)
    raster = np.zeros(shape, dtype=bool)
    ix = np.floor(end[on_plane] / cell).astype(np.int64)
    raster[ix[:, 0], ix[:, 1]] = True
    cells = (np.argwhere(raster) + 0.5) * cell
    cells.setflags(write=False)
    return cells


def region_stats(spec: TaskSpec) -> RegionStats:
    """Measure the test region of ``spec`` at its initial link lengths."""
    cells = reachable_cells(spec)
    y_min = spec.region.test_y_min
    targets, _ = motion_function(*angle_grid().T, *spec.link_lengths, spec.origin)
    return RegionStats(
        test_y_min=y_min,
        link_lengths=tuple(float(v) for v in spec.link_lengths),
        test_area_fraction=float(np.mean(spec.region.contains_test(cells))),
        grid_targets_in_test=int(np.sum(spec.region.contains_test(targets))),
        grid_targets=len(targets),
    )
