"""The residual loop: trace what a model lacks to an effect, add it, report."""
