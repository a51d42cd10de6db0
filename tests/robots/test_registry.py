"""Each robot's defaults: the friction and the estimator its models carry."""

import numpy as np
import pytest

from teleop_force.identification.filtered_regressor import FilterConfig
from teleop_force.identification.pipeline import identify_model
from teleop_force.io.interchange_csv import Recording
from teleop_force.robots.omni import omni_description
from teleop_force.robots.registry import robot_defaults
from teleop_force.simulation.session import teleoperation_protocol


def test_the_omni_carries_the_estimator_chosen_on_plant_family_one() -> None:
    config = robot_defaults("omni").filter_config()
    assert (config.observer_hz, config.observer_prefilter_hz) == (40.0, 40.0)
    assert config.estimator_prefilter == (40.0, 2)
    # what was not chosen for it stays the library's
    library = FilterConfig()
    assert (config.cutoff_hz, config.velocity_cutoff_hz) == (
        library.cutoff_hz,
        library.velocity_cutoff_hz,
    )


@pytest.mark.parametrize("robot", ["dvrk-mtm", "teststand", "none", "my_robot.json"])
def test_robots_without_contact_data_keep_the_library_estimator(robot) -> None:
    assert robot_defaults(robot).filter_config() == FilterConfig()
    assert FilterConfig().estimator_prefilter == (FilterConfig().velocity_cutoff_hz, 1)


def test_identify_gives_an_omni_model_the_omnis_estimator() -> None:
    session = teleoperation_protocol(4.0, seed=3)
    recording = Recording(session.t_s, session.q_rad, session.tau_nm)
    model, _ = identify_model([recording], omni_description(), "coupled-cv")
    assert model.filter_config == robot_defaults("omni").filter_config()
    given = FilterConfig(observer_hz=12.0)
    model, _ = identify_model([recording], omni_description(), "coupled-cv", config=given)
    assert model.filter_config is given
    assert np.isfinite(model.base_values).all()
