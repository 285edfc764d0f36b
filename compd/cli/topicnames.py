"""The names of ``compd help``'s topic pages, for the parser (the pages are in :mod:`compd.cli.topics`)."""

#: The topic pages and what each says (the pages are in :mod:`compd.cli.topics`).
TOPICS = {
    "config": "the daemon config's sections and keys, with types, bounds and defaults",
    "model-file": "the model file's keys (schema compd.model/1), with types and bounds",
    "units": "the unit suffixes of signal and column names",
    "status-word": "the status word's bits, written to the PLC beside the offsets",
    "exit-codes": "what compd's exit status means",
    "references": "the papers compd's methods come from, by the short names its help cites",
}
