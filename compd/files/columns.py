"""Names every data file shares: columns and the recorder's metadata keys.

Apart from the pandas reader, so the daemon's recorder can use them.
"""

TIME_SECONDS = "time_s"
TIMESTAMP_NAMES = ("time", "timestamp", "datetime")
#: Names of a data file's time column, in the order the reader looks for them.
TIME_NAMES = (TIME_SECONDS, *TIMESTAMP_NAMES)

# A recording's metadata keys that mark its run (:mod:`compd.files.runs` says what each means).
MACHINE_ID = "machine_id"
RUN_ID = "run_id"
RUN_FILE = "run_file"
RUN_PREVIOUS = "run_previous"
RUN_REASON = "run_reason"
RUN_GAP_S = "run_gap_s"
#: ``unit.<column>``: the column's unit, as the config's signal names it.
UNIT_PREFIX = "unit."

#: Columns compd's recorder adds beside the signals: what it did, not what the machine measured.
RECORDED_PREFIXES = ("health.", "read.", "model.", "offset.", "readback.", "gain.", "probe.")
RECORDED_NAMES = ("status", "heartbeat", "t_s")


def is_recorded_column(name: str) -> bool:
    """Whether ``name`` is one of the recorder's own columns (status, health, model outputs...)."""
    return name in RECORDED_NAMES or name.startswith(RECORDED_PREFIXES)
