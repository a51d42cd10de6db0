"""Friction models, all linear in their parameters."""
