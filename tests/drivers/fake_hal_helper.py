"""A stand-in for compd's LinuxCNC HAL helper that answers with whatever a test wrote.

Run as ``python fake_hal_helper.py REPLIES`` (through :func:`install`'s
wrapper, which the driver starts as its ``python``): it answers an ``open``
with ``{"ok": null}`` as the real helper does, and every other request with
the next line of the file ``REPLIES``, read afresh for each request, in
turn; the count of replies sent is kept in ``REPLIES.count``, so a new
helper (after the driver reconnects) goes on where the last one stopped.
Standard library only.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path


def install(folder: Path, replies: list[str]) -> tuple[Path, Path]:
    """Write ``replies`` (one per line) and an executable wrapper; returns (wrapper, replies file)."""
    replies_file = folder / "replies.txt"
    replies_file.write_text("".join(f"{line}\n" for line in replies))
    wrapper = folder / "fake-python"
    wrapper.write_text(f'#!/bin/sh\nexec "{sys.executable}" -I "{__file__}" "{replies_file}"\n')
    wrapper.chmod(0o755)
    return wrapper, replies_file


def main() -> None:
    replies = Path(sys.argv[1])
    counter = replies.with_suffix(".count")
    for line in sys.stdin:
        if "open" in json.loads(line):
            sys.stdout.write('{"ok": null}\n')
        else:
            answers = replies.read_text().splitlines() or [""]
            sent = int(counter.read_text()) if counter.exists() else 0
            counter.write_text(str(sent + 1))
            sys.stdout.write(answers[sent % len(answers)] + "\n")
        sys.stdout.flush()


if __name__ == "__main__":
    main()
