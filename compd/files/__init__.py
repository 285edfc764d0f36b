"""The files compd reads and writes: model files, data records, YAML places, the effect catalogue."""
