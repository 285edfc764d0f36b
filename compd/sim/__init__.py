"""The thermal twin of a 3-axis milling centre: a simulated machine for tests and trying compd."""
