"""Gaussian radial-basis-function networks with on-line weight adaptation (3.66-3.75, 3.79-3.81;
2.65-2.73 in chapter 2).

Every element k of an approximated matrix or vector is theta_k^T xi(x), with activations
xi_i(x) = exp(-|x - mu_i|^2 / sigma^2) (3.69) of fixed centres mu_i. All elements share
the centres, so a network is a weight matrix theta (nodes x elements): output = xi^T theta,
and the laws theta_k' = Gamma xi(x) y_k (3.79-3.81) are one outer product per cycle.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


def grid_centres(low: np.ndarray, high: np.ndarray, per_dim: int) -> np.ndarray:
    """Centres evenly spread over the box [low, high], per_dim per dimension (rows)."""
    axes = [np.linspace(lo, hi, per_dim) if per_dim > 1 else np.array([(lo + hi) / 2])
            for lo, hi in zip(low, high, strict=True)]
    return np.ascontiguousarray(
        np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, len(low)))


def halton_centres(low: np.ndarray, high: np.ndarray, count: int) -> np.ndarray:
    """``count`` centres spread over the box [low, high] by the Halton sequence (bases the
    first primes, index from 1): an even, deterministic cover where a grid would need
    per_dim^dim nodes (a 7-joint arm's 14-dimensional (q, q') input)."""
    primes = [2, 3, 5, 7, 11, 13, 17, 19, 23, 29, 31, 37, 41, 43, 47, 53, 59, 61, 67, 71]
    dim = len(low)
    if dim > len(primes):
        raise ValueError(f"halton_centres supports up to {len(primes)} dimensions, got {dim}")
    points = np.empty((count, dim))
    for j in range(dim):
        base = primes[j]
        for i in range(count):
            k, f, x = i + 1, 1.0, 0.0
            while k > 0:
                f /= base
                x += f * (k % base)
                k //= base
            points[i, j] = x
    return np.ascontiguousarray(np.asarray(low) + points * (np.asarray(high) - np.asarray(low)))


def centres(low: np.ndarray, high: np.ndarray, per_dim: int, max_nodes: int) -> np.ndarray:
    """A grid of per_dim centres per dimension if it has at most ``max_nodes`` nodes, else
    ``max_nodes`` Halton centres over the same box."""
    if per_dim ** len(low) <= max_nodes:
        return grid_centres(low, high, per_dim)
    return halton_centres(low, high, max_nodes)


@njit(cache=True, error_model="numpy")
def activations(centres, inv_variance, x):
    """xi_i(x) = exp(-|x - mu_i|^2 / sigma^2) (3.69) for every centre mu_i (rows)."""
    nodes, dim = centres.shape
    xi = np.empty(nodes)
    for i in range(nodes):
        d2 = 0.0
        for j in range(dim):
            diff = centres[i, j] - x[j]
            d2 += diff * diff
        xi[i] = math.exp(-inv_variance * d2)
    return xi


@njit(cache=True, error_model="numpy")
def adapt(theta, xi, gain_dt, y):
    """theta += gain_dt * xi y^T: one explicit Euler step of theta_k' = Gamma xi y_k."""
    nodes, elements = theta.shape
    for i in range(nodes):
        g = gain_dt * xi[i]
        for k in range(elements):
            theta[i, k] += g * y[k]


@njit(cache=True, error_model="numpy")
def output(xi, theta):
    """xi^T theta: every element's estimate theta_k^T xi."""
    nodes, elements = theta.shape
    out = np.zeros(elements)
    for i in range(nodes):
        for k in range(elements):
            out[k] += xi[i] * theta[i, k]
    return out
