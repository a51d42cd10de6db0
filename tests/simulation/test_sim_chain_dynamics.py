import numpy as np
import pinocchio as pin
import pytest

from teleop_force.errors import ModelError
from teleop_force.robots.dvrk_mtm import dvrk_mtm_description
from teleop_force.robots.omni import omni_description
from teleop_force.simulation.chain_dynamics import chain_table, motor_terms
from teleop_force.simulation.perturbed_omni import perturbed_omni_description


@pytest.mark.parametrize("perturbed", [False, True])
def test_terms_match_pinocchio(perturbed: bool) -> None:
    description = (
        perturbed_omni_description(np.random.default_rng(3)) if perturbed else omni_description()
    )
    model = description.model
    assert model is not None
    data = model.createData()
    table = chain_table(description)
    coupling = description.coupling
    rng = np.random.default_rng(0)
    for _ in range(5):
        q, qd = rng.uniform(-1.0, 1.0, 3), rng.uniform(-3.0, 3.0, 3)
        mass, bias, jac, tip = np.empty((3, 3)), np.empty(3), np.empty((3, 3)), np.empty(3)
        motor_terms(table, q, qd, mass, bias, jac, tip)
        q_model, qd_model = coupling @ q, coupling @ qd
        m_model = pin.crba(model, data, q_model)
        m_model = np.triu(m_model) + np.triu(m_model, 1).T
        expected_mass = coupling.T @ m_model @ coupling + np.diag(description.rotor_inertia_kgm2)
        expected_bias = coupling.T @ pin.rnea(model, data, q_model, qd_model, np.zeros(3))
        frame = model.getFrameId("tip")
        jac6 = pin.computeFrameJacobian(model, data, q_model, frame, pin.LOCAL_WORLD_ALIGNED)
        np.testing.assert_allclose(mass, expected_mass, atol=1e-14)
        np.testing.assert_allclose(bias, expected_bias, atol=1e-13)
        np.testing.assert_allclose(jac, jac6[:3] @ coupling, atol=1e-14)
        np.testing.assert_allclose(tip, data.oMf[frame].translation, atol=1e-14)


def test_refuses_other_chains() -> None:
    with pytest.raises(ModelError):
        chain_table(dvrk_mtm_description())
