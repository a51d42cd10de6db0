"""Fuzzing of every decoder and reader (hypothesis); ``python -m tests.fuzz.report`` counts."""
