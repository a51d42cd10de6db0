"""Robot descriptions (built-in and from files), kinematics, and the Device interface."""
