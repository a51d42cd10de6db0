"""Shared test cases of the estimation tests: a coupled-CV friction and a random network."""

from __future__ import annotations

import numpy as np

from teleop_force.friction.coulomb_viscous import CoupledCoulombViscous
from teleop_force.friction.wavelet_network import WaveletNetwork, omni_wavelet_specs
from teleop_force.robots.omni import omni_description

CV_PARAMETERS = np.array([0.02, 0.002, 0.02, 0.01, 0.003, 0.004, 0.01, 0.002, 0.018, 0.005])


def random_network(
    seed: int = 0,
    wavelets_per_joint: int = 120,
    trained_rad_s: float = 0.6,
    on_fallback: bool = False,
) -> WaveletNetwork:
    """A network of random pool wavelets over a coupled-CV fallback (``on_fallback``: adds to it).

    Its coverage map counts 20,000 velocities uniform in ``+-trained_rad_s``: below the
    motion's speeds the blend weights lie strictly between 0 and 1.
    """
    description = omni_description()
    fallback = CoupledCoulombViscous(3, description.friction_inputs, CV_PARAMETERS)
    net = WaveletNetwork(
        3, omni_wavelet_specs(2.0, 2.0), fallback=fallback, on_fallback=on_fallback
    )
    rng = np.random.default_rng(seed)
    for j in range(3):
        sl = net.pool.joint_slice(j)
        idx = rng.choice(np.arange(sl.start, sl.stop), size=wavelets_per_joint, replace=False)
        net.set_structure(j, idx, rng.normal(0.0, 1e-3, idx.size))
    assert net.coverage is not None
    net.coverage.add(rng.uniform(-trained_rad_s, trained_rad_s, size=(20_000, 3)))
    return net
