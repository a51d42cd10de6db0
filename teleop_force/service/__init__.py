"""The force-estimation service: joint states in, force estimates out, over Zenoh."""
