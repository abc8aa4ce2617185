"""Clustering the obstacle points: connected components of a bird's-eye occupancy grid, or
Euclidean clustering (points closer than a radius are linked; KD-tree + graph components)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

_EIGHT = np.ones((3, 3), dtype=bool)


def grid_clusters(xy: NDArray[np.float32], cell: float) -> NDArray[np.int64]:
    """Cluster id of each point: 8-connected occupied cells of a ``cell``-metre BEV grid."""
    if len(xy) == 0:
        return np.zeros(0, dtype=np.int64)
    ij = np.floor((xy - xy.min(axis=0)) / cell).astype(np.int64)
    shape = tuple(ij.max(axis=0) + 1)
    occupied = np.zeros(shape, dtype=bool)
    occupied[ij[:, 0], ij[:, 1]] = True
    labels, _ = ndimage.label(occupied, structure=_EIGHT)
    return labels[ij[:, 0], ij[:, 1]].astype(np.int64) - 1


def euclidean_clusters(xyz: NDArray[np.float32], radius: float) -> NDArray[np.int64]:
    """Cluster id of each point: components of the graph linking points within ``radius`` (3D)."""
    n = len(xyz)
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    pairs = cKDTree(xyz).query_pairs(radius, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs), dtype=np.int8), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    return labels.astype(np.int64)


def split_clusters(labels: NDArray[np.int64], min_points: int, max_points: int) -> list[NDArray[np.int64]]:
    """Point indices of each cluster with between ``min_points`` and ``max_points`` points."""
    if len(labels) == 0:
        return []
    order = np.argsort(labels, kind="stable")
    sorted_labels = labels[order]
    starts = np.flatnonzero(np.r_[True, sorted_labels[1:] != sorted_labels[:-1]])
    ends = np.r_[starts[1:], len(labels)]
    return [order[s:e] for s, e in zip(starts, ends, strict=True) if min_points <= e - s <= max_points]
