"""``teleop-force bench``: performance figures measured in one run."""
