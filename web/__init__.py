"""teleop-force browser dashboard (viser); run with ``python -m web``."""
