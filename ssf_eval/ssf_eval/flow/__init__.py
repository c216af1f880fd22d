"""Scene flow evaluation: metrics, the estimator table, the error picture, speed."""
