"""A live view on the terminal that nothing else writes over: the view, and under it a log panel.

rich's :class:`~rich.live.Live` redraws its region by moving the cursor up
over the lines it drew last. Any other line written to that terminal (a log
handler holding the real stderr, a print) shifts the region, and every redraw
after it leaves a stale copy of the view above: the "ghost" headers. So while
the view is shown, the root logger's handlers that write to this terminal are
set aside for a :class:`LogPanel` that keeps the records: WARNING and up show
in a panel under the view, and when the view ends every record kept is
handed to the handlers set aside, in full (stderr, journald). That begins
with the first frame, not on entering: what is logged before it (the
start-up: model, socket, drivers connected) is on the terminal as it comes,
above the view, not held back until the view has ended; its warnings are in
the panel too. A view taller
than the terminal would scroll and leave ghosts too: the panel shrinks first,
then the view is cropped to the terminal's height.
"""

from __future__ import annotations

import logging
import sys
import threading
from collections import deque
from types import TracebackType
from typing import Any, Self

from rich.console import Console, Group, RenderableType
from rich.live import Live
from rich.panel import Panel
from rich.text import Text

#: Real seconds between two frames of a live view.
FRAME_S = 0.25

#: Records kept while the view runs, handed on in full when it ends.
KEEP_RECORDS = 2000

_STYLE = {logging.WARNING: "yellow", logging.ERROR: "bold red", logging.CRITICAL: "bold red"}


class LogPanel(logging.Handler):
    """Keeps every record; shows the last WARNING-and-up records' first lines in a panel."""

    def __init__(self, formatter: logging.Formatter | None, shown: int = 6) -> None:
        super().__init__()
        self.setFormatter(formatter or logging.Formatter("%(levelname)s %(name)s: %(message)s"))
        #: Each record kept, formatted when it came (a stdlib record's time is stamped when
        #: formatted): its level and its text.
        self.records: deque[tuple[int, str]] = deque(maxlen=KEEP_RECORDS)
        self.dropped = 0
        self.warnings = 0
        self.lines: deque[tuple[int, str]] = deque(maxlen=shown)
        self._lines_lock = threading.Lock()
        #: False while the terminal's handlers still write each record (before the first
        #: frame): the panel counts and shows warnings, and keeps nothing to hand on.
        self.keep = True

    def emit(self, record: logging.LogRecord) -> None:
        if self.keep and len(self.records) == self.records.maxlen:
            self.dropped += 1
        try:
            text = self.format(record)
        except Exception:  # a record that cannot be formatted must not end the view
            text = f"{record.levelname} {record.name}: {record.msg!r}"
        if self.keep:
            self.records.append((record.levelno, text))
        if record.levelno >= logging.WARNING:
            self.warnings += 1
            line = Text.from_ansi(text.split("\n", 1)[0]).plain
            with self._lines_lock:
                self.lines.append((record.levelno, line))

    def panel(self, rows: int) -> Panel | None:
        """The last ``rows`` warning lines in a panel of ``rows + 2`` lines; None when nothing to show."""
        if rows < 1:
            return None
        if not self.lines:
            body = Text("none so far", "dim")
        else:
            with self._lines_lock:  # records come from worker threads too
                lines = list(self.lines)[-rows:]
            body = Text()
            for i, (level, line) in enumerate(lines):
                body.append(("\n" if i else "") + line, _STYLE.get(level, "yellow"))
            body.no_wrap = True
            body.overflow = "ellipsis"
        return Panel(
            body,
            title=f"warnings and errors ({self.warnings})",
            title_align="left",
            border_style="yellow" if self.lines else "dim",
        )


class LiveScreen:
    """``with LiveScreen(console) as screen: screen.show(view)``: one live region, logs in its panel."""

    def __init__(self, console: Console, *, panel_rows: int = 6) -> None:
        self.console = console
        self.panel_rows = panel_rows
        root = logging.getLogger()
        writes_here = [
            h for h in root.handlers if isinstance(h, logging.StreamHandler) and _on_terminal(h)
        ]
        formatter = writes_here[0].formatter if writes_here else None
        self.logs = LogPanel(formatter, shown=panel_rows)
        self._set_aside: list[logging.StreamHandler[Any]] = writes_here
        #: Whether the first frame was drawn (the handlers set aside, the region live).
        self.started = False
        self.live = Live(
            console=console,
            auto_refresh=False,
            transient=False,
            vertical_overflow="crop",
            redirect_stdout=True,
            redirect_stderr=True,
        )

    def __enter__(self) -> Self:
        # Until the first frame the terminal's handlers write on; the panel only counts
        # the warnings (a saved state ignored at start-up), to show them under the view.
        self.logs.keep = False
        logging.getLogger().addHandler(self.logs)
        return self

    def _start(self) -> None:
        """Set the terminal's log handlers aside for the panel and start the live region."""
        root = logging.getLogger()
        for handler in self._set_aside:
            root.removeHandler(handler)
        self.logs.keep = True
        self.live.start()
        self.started = True

    def show(self, view: RenderableType) -> None:
        """Draw ``view`` and the log panel, fitted to the terminal's height (the first: the view begins)."""
        if not self.started:
            self._start()
        height = self.console.size.height
        used = len(self.console.render_lines(view, self.console.options, pad=False))
        rows = min(self.panel_rows, height - used - 2)
        panel = self.logs.panel(rows)
        self.live.update(view if panel is None else Group(view, panel), refresh=True)

    def __exit__(
        self,
        kind: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        root = logging.getLogger()
        root.removeHandler(self.logs)
        if not self.started:  # no frame drawn: nothing was set aside
            return
        self.live.stop()
        self.started = False
        for handler in self._set_aside:
            root.addHandler(handler)
        if not self._set_aside:
            return
        if self.logs.dropped:
            print(f"({self.logs.dropped} earlier log records not kept)", file=sys.stderr)
        for level, text in self.logs.records:
            for handler in self._set_aside:
                if level >= handler.level:
                    handler.stream.write(text + handler.terminator)
                    handler.flush()


def _on_terminal(handler: logging.StreamHandler[Any]) -> bool:
    """Whether ``handler`` writes to a terminal (and so over the live view)."""
    isatty = getattr(handler.stream, "isatty", None)
    return bool(callable(isatty) and isatty())
