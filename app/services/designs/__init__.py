"""Engine models, estimator designs and their evaluation."""
