"""Column names every data file shares, apart from the pandas reader so the daemon's recorder can use them."""

TIME_SECONDS = "time_s"
TIMESTAMP_NAMES = ("time", "timestamp", "datetime")
#: Names of a data file's time column, in the order the reader looks for them.
TIME_NAMES = (TIME_SECONDS, *TIMESTAMP_NAMES)
