"""Multilinear interpolation on a rectilinear grid of operating conditions.

A grid is one sorted axis of distinct values per scheduling variable; a value over the grid is
an array [n_1, ..., n_k, ...] (node values first, any trailing shape). At a query the value is
the weighted sum of the 2^k corners of its cell, weights products of the fractions along each
axis: every node is reproduced exactly and between nodes every entry lies between its corner
values. An axis of one value is constant along its variable; queries outside the grid are
clipped to its edges. Used by the built-in engine's schedule (``estimation.engine.schedule``)
and by the model schedules of other engine types (``estimation.schedule``).
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy import sparse

from estimation.model import MATRIX_NAMES, LinearModel

GAIN_NAMES = ("Gy", "Gz", "Guy", "Guz")


@dataclass(frozen=True, eq=False)
class Grid:
    """Axes [n_i] of a rectilinear grid, one per scheduling variable, sorted and distinct."""

    axes: tuple[np.ndarray, ...]

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(len(a) for a in self.axes)

    def weights(self, cond: np.ndarray) -> tuple[tuple[np.ndarray, ...], np.ndarray]:
        """Corner indices and weights of multilinear interpolation for cond [K, n_axes]: one
        index array [C, K] per axis and the weights [C, K] of the cell's C = 2^n_axes corners
        (``itertools.product`` order; a corner beyond a one-node axis has weight 0). Each
        weight is the product of the fractions along the axes, taken in axis order."""
        bits = np.array(list(itertools.product((0, 1), repeat=len(self.axes))), dtype=int)
        w = np.ones((bits.shape[0], cond.shape[0]))
        idx = []
        for k, ax in enumerate(self.axes):
            c = np.clip(cond[:, k], ax[0], ax[-1])
            bit = bits[:, k, None]
            if len(ax) == 1:  # the corner beyond it: a fraction of 0
                lo = np.zeros(len(c), dtype=int)
                frac = np.zeros(len(c))
            else:
                lo = np.clip(np.searchsorted(ax, c, side="right") - 1, 0, len(ax) - 2)
                frac = (c - ax[lo]) / (ax[lo + 1] - ax[lo])
            w = w * np.where(bit == 1, frac, 1.0 - frac)
            idx.append(np.minimum(lo + bit, len(ax) - 1))
        return tuple(idx), w

    def interpolate(self, values: np.ndarray, cond: np.ndarray) -> np.ndarray:
        """``values`` [*shape, ...] at conditions cond [K, n_axes]: [K, ...]."""
        return _corner_sum(values, *self.weights(cond))

    def interpolate_all(self, values: Mapping[str, np.ndarray], names: Iterable[str],
                        cond: np.ndarray) -> dict[str, np.ndarray]:
        """Several stacks over the grid at the same conditions (the weights found once):
        name -> [K, ...], each as ``interpolate`` gives it."""
        idx, w = self.weights(cond)
        return {n: _corner_sum(values[n], idx, w) for n in names}

    def corners(self, cond: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Flat node indices and weights [C, K] of multilinear interpolation at conditions
        cond [K, n_axes], the corners of a one-node axis left out: with ``flat`` the values
        over the grid's nodes [n_nodes, F] (C-order), the interpolated values are
        sum_c weights[c, :, None] * flat[indices[c]]."""
        idx, w = self.weights(cond)
        bits = np.array(list(itertools.product((0, 1), repeat=len(self.axes))), dtype=bool)
        kept = ~(bits & (np.array(self.shape) == 1)).any(axis=1)
        return np.ravel_multi_index(tuple(i[kept] for i in idx), self.shape), w[kept]


def _corner_sum(values: np.ndarray, idx: tuple[np.ndarray, ...], w: np.ndarray) -> np.ndarray:
    """sum_c w[c] values[idx[c]] over the corners in order: [K, ...]."""
    acc = np.zeros(w.shape[1:] + values.shape[len(idx):])
    shape = (-1,) + (1,) * (acc.ndim - 1)
    for c in range(w.shape[0]):
        acc += w[c].reshape(shape) * values[tuple(i[c] for i in idx)]
    return acc


def corner_sums(indices: np.ndarray, weights: np.ndarray, flat: np.ndarray) -> np.ndarray:
    """sum_c weights[c, :, None] * flat[indices[c]] -> [K, F] for the corners (``Grid.corners``)
    of K queries and values over the nodes flat [n_nodes, F]: one sparse product (each query a
    row of its C weights), a single pass over the values instead of one gathered copy per
    corner. Each row's sum runs over its corners in order, as the formula reads, so a query's
    value does not depend on the other queries of the call (nor on the other columns)."""
    return np.asarray(corner_rows(indices, weights, flat.shape[0]) @ flat)


def corner_rows(indices: np.ndarray, weights: np.ndarray, n_nodes: int) -> sparse.csr_matrix:
    """The sparse [K, n_nodes] of ``corner_sums``: each query a row of its C weights, in corner
    order; its product with any values over the nodes is their ``corner_sums``."""
    C, K = indices.shape
    return sparse.csr_matrix(
        (np.ascontiguousarray(weights.T).ravel(), np.ascontiguousarray(indices.T).ravel(),
         np.arange(0, C * K + 1, C)), shape=(K, n_nodes))


def model_stacks(models: Sequence[LinearModel], shape: tuple[int, ...]) -> dict[str, np.ndarray]:
    """The matrices A..N and steady-state gains (``GAIN_NAMES``: G_y, G_z of docs/math.md
    section 1 and those of the inputs) of models at the grid's nodes (C-order), each stacked
    over the grid: name -> [*shape, rows, columns]."""
    values: dict[str, np.ndarray] = {}
    for m in MATRIX_NAMES:
        values[m] = np.stack([getattr(mod, m) for mod in models]).reshape(
            shape + getattr(models[0], m).shape)
    gains = [mod.steady_state_gains() + mod.steady_state_input_gains() for mod in models]
    for j, g in enumerate(GAIN_NAMES):
        values[g] = np.stack([gg[j] for gg in gains]).reshape(shape + gains[0][j].shape)
    return values
