"""Bundled example models, data and configuration (installed as ``compd.bundled``)."""
