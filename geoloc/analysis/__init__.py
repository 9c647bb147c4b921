"""Analysis: error models, Monte Carlo, calibration and error reports (docs/architecture.md)."""
