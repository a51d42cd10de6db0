"""Sensorless contact-force estimation for teleoperated haptic robots."""
