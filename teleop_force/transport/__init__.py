"""Zenoh transport: key expressions, wire messages, sessions, routers, stream statistics."""
