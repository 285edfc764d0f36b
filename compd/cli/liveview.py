"""``compd read`` and ``compd probe`` at work: the points to read, the table, the watch loop, the write.

The table shows per point the raw reading (registers, image bytes, a node's
variant, a reply field), the device's value (the address's own type, as the
driver's ``read`` gives it), the decoded value (a signal's scale and offset,
an offset's encoding, as the daemon applies them), the unit and the verdict.
With ``--watch`` it refreshes in place on a terminal (``rich.live``) and
prints one table (or one JSON line) per read elsewhere, on absolute
deadlines ``next_s += interval_s``. A probe's write is refused unless it is
confirmed on a terminal (typing the address) or ``--yes`` is given.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import sys
import time
from collections.abc import Callable, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

import structlog
import yaml
from pydantic import BaseModel, ValidationError
from rich.console import Console
from rich.table import Table
from rich.text import Text

from compd.cli.livepoints import LiveDriver, LivePoint, LiveReader, Row
from compd.cli.terminal import console
from compd.drivers.base import DriverType, address_syntax, check_address, reads_back
from compd.drivers.registry import (
    DriverImportError,
    UnknownDriverError,
    driver_names,
    load_driver_type,
)
from compd.errors import CompdError, DriverError, InputFileError
from compd.files.keyhints import unknown_key_hint
from compd.files.yamlplace import describe, parse_yaml, read_limited, resolve_path

if TYPE_CHECKING:
    from compd.service.config.loading import Config

#: Exit status when a point could not be read or failed its checks (2 stays "bad input").
EXIT_POINT_FAILED = 1

# -- compd read -------------------------------------------------------------


def read_command(args: argparse.Namespace) -> int:
    # The config's checks load the model file's stack (scipy, ~3 s on an edge PC): read only.
    from compd.cli.serving import config_from_arg

    _quiet_logs()
    config = config_from_arg(args.config)
    points = config_points(config, args.names)
    used = {p.driver for p in points}
    drivers = {
        name: LiveDriver(
            name,
            driver,
            config.doc.drivers[name].timeout_s,
            serial=_on_serial_line(config.doc.drivers[name].type, config.driver_settings[name]),
        )
        for name, driver in config.build_drivers(time.monotonic).items()
        if name in used
    }
    return _run(LiveReader(points, drivers), args, f"compd read {config.path.name}")


def config_points(config: Config, names: Sequence[str]) -> list[LivePoint]:
    """The signals (all, or those named), then the offsets and status words their drivers read back."""
    doc = config.doc
    unknown = [n for n in names if n not in doc.signals and n not in doc.outputs]
    if unknown:
        raise CompdError(
            f"{config.path}: no signal or output named {unknown[0]!r}; "
            f"signals: {', '.join(doc.signals)}; outputs: {', '.join(doc.outputs)}"
        )
    points = [
        LivePoint(
            name,
            "signal",
            signal.driver,
            signal.address,
            signal.unit,
            signal.point(name).convert,
            signal.monitor(name),
        )
        for name, signal in doc.signals.items()
        if not names or name in names
    ]
    for axis in config.axis_points():
        if names and axis.name not in names:
            continue
        if not _reads_back(config, axis.driver):
            if names:
                raise CompdError(
                    f"{config.path}: output {axis.name!r} is on driver {axis.driver!r}, which "
                    "cannot read back what the device holds; there is nothing to read"
                )
            continue
        points.append(
            LivePoint(f"offset {axis.name}", "output", axis.driver, axis.address, "um", axis.decode)
        )
    status = doc.status
    if status is not None and not names and _reads_back(config, status.driver):
        for label, address in (
            ("status word", status.status_address),
            ("heartbeat", status.heartbeat_address),
        ):
            points.append(LivePoint(label, "status", status.driver, address))
    return points


def _reads_back(config: Config, driver: str) -> bool:
    kind = load_driver_type(config.doc.drivers[driver].type)
    answer: bool = reads_back(kind, config.driver_settings[driver])
    return answer


def _on_serial_line(type_name: str, settings: BaseModel) -> bool:
    """A serial port one process at a time may own: a busy one gets a hint naming the daemon."""
    return type_name == "serial_sensor" or getattr(settings, "transport", None) == "rtu"


# -- compd probe ------------------------------------------------------------


def probe_command(args: argparse.Namespace) -> int:
    _quiet_logs()
    kind = _driver_type(args.type)
    settings, base_dir, summary = probe_settings(kind, args)
    value = None if args.write is None else _write_value(args.write)
    if value is not None and len(args.addresses) != 1:
        raise CompdError("--write takes exactly one ADDRESS: write one value at a time")
    for address in args.addresses:
        try:
            check_address(kind, address, writable=value is not None, settings=settings)
        except ValueError as exc:
            raise CompdError(
                f"address {address!r} for driver type {args.type!r}: {exc}. "
                f"Write it {address_syntax(kind)}"
            ) from None
    target = f"{args.type} ({summary})" if summary else args.type

    def reader() -> LiveReader:
        driver = kind(settings, now=time.monotonic, base_dir=base_dir)
        serial = _on_serial_line(args.type, settings)
        live = LiveDriver(args.type, driver, args.timeout_s, serial=serial)
        return LiveReader(
            [LivePoint(a, "probe", args.type, a) for a in args.addresses], {args.type: live}
        )

    if value is None:
        return _run(reader(), args, f"compd probe {target}")
    address = args.addresses[0]
    if not args.yes:
        if not sys.stdin.isatty():
            raise CompdError(
                f"refusing to write {args.write} to {address} on {target}: there is no terminal "
                "to confirm on. Check the address and value, then pass --yes to write from a script"
            )
        once = argparse.Namespace(**{**vars(args), "watch": False, "json": False})
        if _run(reader(), once, f"compd probe {target}: now") != 0:
            raise CompdError(f"{address} cannot be read now (see above): nothing written")
        _confirm(console(), address, args.write, target)
    return _run(
        reader(), args, f"compd probe {target}: wrote {args.write} to {address}", write=value
    )


def probe_settings(kind: DriverType, args: argparse.Namespace) -> tuple[BaseModel, Path, str]:
    """The driver's settings from ``--settings FILE`` and ``--set`` pairs, validated by its type.

    Also the folder relative file names resolve from, and a summary for people (no secrets).
    """
    data: dict[str, Any] = {}
    base_dir = Path.cwd()
    source = "--set"
    if args.settings:
        path = resolve_path(args.settings, Path.cwd())
        text = read_limited(path, InputFileError).decode("utf-8", errors="replace")
        loaded, _ = parse_yaml(text, path, InputFileError)
        if not isinstance(loaded, dict):
            raise InputFileError(
                path,
                "is not a mapping of driver settings",
                where="top level",
                fix="Write the keys that go under drivers.NAME.settings, e.g. 'host: 10.0.0.5'",
            )
        data, base_dir, source = loaded, path.parent, f"--settings {path} / --set"
    shown: list[str] = []
    for pair in args.pairs:
        key, sep, text = pair.partition("=")
        if not sep or not key:
            raise CompdError(f"--set {pair!r} is not KEY=VALUE (e.g. --set host=192.168.0.10)")
        *parents, leaf = key.split(".")
        place = data
        for part in parents:
            place = place.setdefault(part, {})
            if not isinstance(place, dict):
                raise CompdError(f"--set {pair!r}: {part!r} is not a mapping of settings")
        place[leaf] = _yaml_scalar(text)
        if not any(word in key.lower() for word in ("password", "secret", "key")):
            shown.append(f"{key}={text}")
    try:
        settings = kind.settings_model.model_validate(data)
    except ValidationError as exc:
        first = sorted(exc.errors(), key=lambda e: e["type"] != "extra_forbidden")[0]
        key = ".".join(str(p) for p in first["loc"]) or "settings"
        keys = "keys as under drivers.NAME.settings, see config/compd.example.yaml"
        if first["type"] == "extra_forbidden":
            keys = unknown_key_hint(kind.settings_model, first["loc"]) or keys
        raise CompdError(
            f"driver type {args.type!r} settings ({source}): {key}: {describe(first)}. "
            f"Fix it with --set KEY=VALUE ({keys})"
        ) from None
    if args.settings:
        shown.insert(0, f"settings {args.settings}")
    return settings, base_dir, ", ".join(shown)


def _driver_type(name: str) -> DriverType:
    try:
        return load_driver_type(name)
    except UnknownDriverError:
        raise CompdError(f"unknown driver type {name!r}; use one of {driver_names()}") from None
    except DriverImportError as exc:
        raise CompdError(f"{exc}. Install the library it names") from None


def _yaml_scalar(text: str) -> Any:
    """A ``--set`` value as YAML reads it (``502`` a number, ``true`` a bool), else the text."""
    try:
        return yaml.safe_load(text) if text else ""
    except yaml.YAMLError:
        return text


def _write_value(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise CompdError(
            f"--write {text!r} is not a number (write a bool as 1 or 0; no scaling is applied)"
        ) from None


def _confirm(out: Console, address: str, value: str, target: str) -> None:
    """Ask on the terminal; anything but the address typed back writes nothing."""
    prompt = Text.assemble((f"Write {value} to {address}", "bold"), f" on {target}?")
    out.print(prompt)  # Text: the address and target literally, never markup or emoji
    answer = out.input(Text(f"Type the address ({address}) to confirm, anything else cancels: "))
    if answer.strip() != address:
        raise CompdError("not confirmed: nothing written")


# -- reading, showing -------------------------------------------------------


def _quiet_logs() -> None:
    """Drivers' log lines to stderr, WARNING and up: the table shows each fault already."""
    structlog.configure(
        wrapper_class=structlog.make_filtering_bound_logger(logging.WARNING),
        logger_factory=structlog.PrintLoggerFactory(sys.stderr),
        cache_logger_on_first_use=False,
    )


def _run(
    reader: LiveReader, args: argparse.Namespace, title: str, *, write: float | None = None
) -> int:
    """Read once or watch, show each read; exit status 1 if the last read had a failed point."""
    try:
        rows = asyncio.run(_session(reader, args, title, write))
    except KeyboardInterrupt:  # Ctrl-C ends --watch; the drivers were closed on the way out
        rows = reader.last
    return 0 if rows and all(r.ok for r in rows) else EXIT_POINT_FAILED


async def _session(
    reader: LiveReader, args: argparse.Namespace, title: str, write: float | None
) -> list[Row]:
    out = console()
    try:
        if write is not None:
            live = next(iter(reader.drivers.values()))
            try:
                await live.write(reader.points[0].address, write)
            except DriverError as exc:
                out.print(Text(f"compd: {exc}; nothing else done", style="red"))
                return []
        if args.watch and not args.json and out.is_terminal:
            from rich.live import Live  # only a watching terminal needs it

            with Live(console=out, auto_refresh=False) as screen:
                return await _loop(
                    reader,
                    args,
                    lambda rows, _: screen.update(_table(rows, f"{title}  {_now()}"), refresh=True),
                )
        return await _loop(reader, args, lambda rows, n: _print(out, rows, n, title, args))
    finally:
        await reader.close()


async def _loop(
    reader: LiveReader, args: argparse.Namespace, show: Callable[[list[Row], int], None]
) -> list[Row]:
    """Read and show, on absolute deadlines, until one read (no --watch), --count reads, or Ctrl-C."""
    loop = asyncio.get_running_loop()
    next_s = loop.time()
    while True:
        rows = await reader.read()
        show(rows, reader.reads)
        if not args.watch or (args.count is not None and reader.reads >= args.count):
            return rows
        next_s = max(next_s + args.interval_s, loop.time())  # a slow read skips, never bunches
        await asyncio.sleep(next_s - loop.time())


def _print(out: Console, rows: list[Row], n: int, title: str, args: argparse.Namespace) -> None:
    stamp = _now()
    if args.json:
        record = {"title": title, "read": n, "time": stamp, "points": [r.as_dict() for r in rows]}
        print(json.dumps(record), flush=True)
        return
    out.print(_table(rows, f"{title}  {stamp}" if args.watch else title))


def _table(rows: list[Row], title: str) -> Table:
    """One row per point, without the columns that would only repeat another.

    A probe's point is its address and its value the device's (no scaling, no
    unit); one driver needs no driver column; unscaled points no device column.
    """
    cells: dict[str, list[str]] = {
        "point": [r.point.name for r in rows],
        "driver": [r.point.driver for r in rows],
        "address": [r.point.address for r in rows],
        "raw": [r.raw for r in rows],
        "device": [_number(r.device_value) for r in rows],
        "value": [_number(r.value) for r in rows],
        "unit": [r.point.unit for r in rows],
    }
    if cells["point"] == cells["address"]:
        del cells["point"]
    if len(set(cells["driver"])) <= 1:
        del cells["driver"]
    if cells["device"] == cells["value"]:
        del cells["device"]
    if not any(cells["unit"]):
        del cells["unit"]
    table = Table(title=Text(title), title_justify="left")
    for column, texts in cells.items():
        # Names whole (a narrow terminal folds addresses, raw and health instead).
        table.add_column(
            column,
            justify="right" if column in ("device", "value") else "left",
            min_width=max(map(len, texts)) if column == "point" else None,
            overflow="fold",
        )
    table.add_column("health", overflow="fold")
    for i, row in enumerate(rows):
        health = Text(row.health, style="green" if row.ok else "bold red")
        if row.problem:
            health.append(f" {row.problem}", style="" if row.ok else "red")
        if row.hint:
            health.append(f"\nnote: {row.hint}", style="yellow")
        # Text, not markup: addresses such as holding:100:int32 must not become emoji.
        table.add_row(*(Text(texts[i]) for texts in cells.values()), health)
    return table


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="milliseconds")


def _number(value: float | None) -> str:
    return "" if value is None else f"{value:.6g}"
