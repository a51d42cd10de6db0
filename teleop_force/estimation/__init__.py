"""Contact-force estimation from a dynamic model: the streaming estimator and its kernels."""
