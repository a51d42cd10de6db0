"""Reports regenerated from data: the paper's experiments, the robots, the blind tests."""
