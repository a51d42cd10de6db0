"""The batched momentum-form regressor against the per-sample one it replaces."""

import numpy as np

from teleop_force.identification.regressor import RigidBodyRegressor
from teleop_force.robots.omni import omni_description


def test_momentum_form_batch_equals_per_sample_regressors() -> None:
    regressor = RigidBodyRegressor(omni_description())
    base = regressor.find_base_parameters()
    rng = np.random.default_rng(0)
    q = rng.uniform(-0.5, 1.2, size=(700, 3))
    qd = rng.normal(0.0, 1.0, size=(700, 3))
    qd[:4] = 0.0  # at rest: no directional derivative
    for columns in (base.independent, None):
        y_p, y_w = regressor.momentum_form_batch(q, qd, columns, chunk=256)
        cols = slice(None) if columns is None else columns
        pairs = list(zip(q, qd, strict=True))
        expected_p = np.array([regressor.momentum(a, b)[:, cols] for a, b in pairs])
        expected_w = np.array([regressor.coriolis_gravity(a, b)[:, cols] for a, b in pairs])
        np.testing.assert_allclose(y_p, expected_p, rtol=0, atol=1e-13)
        np.testing.assert_allclose(y_w, expected_w, rtol=0, atol=1e-12)
