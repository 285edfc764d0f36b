"""The modelling toolkit: fit, compare, diagnose, extend, update; built on the files and the numeric core."""
