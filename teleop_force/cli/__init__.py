"""The ``teleop-force`` command line and its demo supervisor."""
