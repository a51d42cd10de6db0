"""Friction models, all linear in their parameters.

One module per model (``coulomb_viscous``, ``model_coordinates``, ``wavelet_network``), their
compiled terms (``terms``), the base class (``base``), the kinds (``kinds``) and reading any of
them from a model file (``model_file``). Nothing is imported here, so that the light modules
(``kinds`` for the CLI's choices) load without numba.
"""
