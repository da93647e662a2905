"""Reference solutions: calibrators, estimators, benchmarks."""
