"""Running compd commands in-process from tests, as a user would type them."""

from __future__ import annotations

import contextlib
import io

from compd.cli import main


def compd(*argv: object) -> str:
    """Run one compd command in-process; its stdout, or a failure showing what it printed."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main([str(a) for a in argv])
    assert code == 0, f"compd {' '.join(map(str, argv))} exited {code}:\n{err.getvalue()}"
    return out.getvalue()


def compd_result(*argv: object) -> tuple[int, str, str]:
    """Run one compd command in-process, whatever its outcome: exit status, stdout, stderr."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main([str(a) for a in argv])
    return code, out.getvalue(), err.getvalue()
