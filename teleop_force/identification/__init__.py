"""From recordings to a dynamic model: regressors, filters, least squares, the pipeline."""
