"""Models shipped with the package.

``omni_sim.json`` is the dynamic model of the simulated Omni used by the demo and by the
force-estimation service by default. It is created by ``python -m
teleop_force.models.make_default``: the paper's identification protocol simulated on the
simulated Omni, identified with the paper's wavelet-network friction (``wn``), its coupled
Coulomb-viscous fallback and the coverage map of its training velocities.
"""

from pathlib import Path
from typing import Final

#: The model the demo and the service load unless told otherwise.
DEFAULT_MODEL_PATH: Final = Path(__file__).resolve().parent / "omni_sim.json"
