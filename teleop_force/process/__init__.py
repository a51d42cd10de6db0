"""Lifetime and memory of the long-running processes (stop signals, malloc trimming)."""
