"""Recordings: the interchange CSV, MCAP sessions, native robot logs, replay."""
