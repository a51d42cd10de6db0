"""Small wavelet networks and exciting velocities shared by the friction tests."""

import numpy as np

from teleop_force.friction.wavelet_network import WaveletJointSpec, WaveletNetwork

FS_HZ = 1000.0


def small_specs() -> list[WaveletJointSpec]:
    one = WaveletJointSpec((0,), (-1.5,), (1.5,), -2, 0, 1e-4, 2e-4)
    two = WaveletJointSpec((1, 2), (-1.5, -1.5), (1.5, 1.5), -2, 0, 1e-4, 2e-4)
    return [one, two, two]


def exciting_velocities(duration_s: float, seed: int = 0, amplitude: float = 1.0) -> tuple:
    n = int(duration_s * FS_HZ)
    t = np.arange(n) / FS_HZ
    rng = np.random.default_rng(seed)
    qd = np.zeros((n, 3))
    for j in range(3):
        for f in rng.uniform(0.2, 1.7, 4):
            qd[:, j] += amplitude * np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi))
    return t, qd


def fixed_network(seed: int, per_joint: int = 6) -> WaveletNetwork:
    """Seeds plus some of their neighbours, random coefficients."""
    net = WaveletNetwork(3, small_specs())
    rng = np.random.default_rng(seed)
    for j in range(3):
        seeds = net.active_global_indices(j)
        extra = net.pool.neighbours(seeds)
        extra = extra[net.pool.m[extra] == 0][: per_joint - seeds.size]
        idx = np.concatenate((seeds, extra))
        net.set_structure(j, idx, rng.normal(0.0, 0.01, idx.size))
    return net
