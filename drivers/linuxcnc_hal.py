"""The HAL side of compd's LinuxCNC driver: a userspace HAL component, run as a helper process.

This file is not imported by compd. :mod:`compd.drivers.linuxcnc` runs it
under the Python that LinuxCNC's ``hal`` module was built for (Debian's
``/usr/bin/python3``) and talks to it over stdin/stdout, one JSON object per
line each way. It uses the standard library and ``hal`` only.

Requests and replies::

    {"open": {"scale": MACHINE_UNITS_PER_COUNT}}   -> {"ok": null}
    {"read": [ADDRESS, ...]}                       -> {"ok": {ADDRESS: VALUE, ...}}
    {"write": {"axis.z": COUNTS, ...}}             -> {"ok": null}
    any failure                                    -> {"error": TEXT, "kind": KIND}

``KIND`` is ``protocol`` (a wrong name: the config's fault) or
``disconnected`` (HAL is not there, or the component was unloaded); after a
failed open or a disconnection the helper exits.

An input ``ADDRESS`` gets an IN pin ``<component>.<ADDRESS>`` of the same
HAL type, linked to the HAL signal ``ADDRESS`` or, when ``ADDRESS`` is an
output pin, to the signal that pin drives (a new signal ``compd:<pin>``
when it drives none). An axis ``axis.L`` gets OUT pins
``<component>.L.eoffset-counts`` (s32), ``-scale`` (float) and ``-enable``
(bit), linked through signals ``compd:L.eoffset-*`` to LinuxCNC's
``axis.L.eoffset-*`` (refused when the HAL file nets those pins to
another signal); reading ``axis.L`` returns the counts the signal
holds. The signals outlive the component, so a new one (after a compd
restart) picks up the counts the machine holds. End of input or SIGTERM
(``halcmd unload``, LinuxCNC shutting down) removes the component and ends
the process.
"""

import contextlib
import json
import signal
import subprocess
import sys

import hal

_TYPES = {1: hal.HAL_BIT, 2: hal.HAL_FLOAT, 3: hal.HAL_S32, 4: hal.HAL_U32}
AXES = "xyzabcuvw"
_AXIS_PINS = (("counts", hal.HAL_S32), ("scale", hal.HAL_FLOAT), ("enable", hal.HAL_BIT))
_OWN_SUFFIXES = {suffix for suffix, _ in _AXIS_PINS}


class Refused(Exception):
    """A request that cannot be served; ``kind`` is 'protocol' or 'disconnected'."""

    def __init__(self, text, kind="protocol"):
        super().__init__(text)
        self.kind = kind


class Component:
    """The component and its pins; rebuilt (same name) when an address is new.

    HAL takes no pins after ``ready()``, and compd names its addresses only
    in its first read and write, so the component starts empty and is
    rebuilt with the union whenever a request names an address it lacks.
    Nothing steps on a rebuild: the signals hold their values meanwhile and
    the new output pins are seeded from them.
    """

    def __init__(self, name, scale):
        self.name = name
        self.scale = scale
        self.inputs = []
        self.axes = []
        self.comp = self._create()
        self.comp.ready()
        if not hal.component_exists("motmod"):
            self.exit()
            raise Refused("LinuxCNC is not running (HAL has no motmod)", "disconnected")

    def _create(self):
        try:
            return hal.component(self.name)
        except Exception as exc:  # hal raises RuntimeError or hal.error, not documented which
            raise Refused(
                f"cannot create HAL component {self.name!r}: {exc}", "disconnected"
            ) from exc

    def ensure(self, addresses):
        """Make sure every address has its pins (``axis.L`` or a signal or output pin name)."""
        self._alive()
        axes = [a[5:] for a in addresses if _is_axis(a) and a[5:] not in self.axes]
        inputs = [a for a in addresses if not _is_axis(a) and a not in self.inputs]
        if not axes and not inputs:
            return
        pins = {p["NAME"]: p for p in hal.get_info_pins()}
        signals = {s["NAME"]: s for s in hal.get_info_signals()}
        inputs, axes = (
            self.inputs + list(dict.fromkeys(inputs)),
            self.axes + list(dict.fromkeys(axes)),
        )
        # Check every name before the old component goes: a bad one changes nothing.
        sources = {a: self._source(a, pins, signals) for a in inputs}
        for axis in axes:
            for suffix, _ in _AXIS_PINS:
                if f"axis.{axis}.eoffset-{suffix}" not in pins:
                    raise Refused(
                        f"LinuxCNC has no pin axis.{axis}.eoffset-{suffix}: "
                        f"is axis {axis.upper()} in [TRAJ]COORDINATES?"
                    )
            _refuse_foreign_nets(axis)
        self.comp.exit()
        self.comp = self._create()
        links = []
        for address, (signal_name, kind) in sources.items():
            if signal_name not in signals:
                _checked(hal.new_sig(signal_name, kind), f"create signal {signal_name}")
                links.append((address, signal_name))
            pin = self.comp.newpin(address, kind, hal.HAL_IN)
            if signal_name in signals:
                # HAL gives a signal without pins the value of the first pin
                # linked: seed it with what the signal holds.
                pin.set(signals[signal_name]["VALUE"])
            links.append((f"{self.name}.{address}", signal_name))
        for axis in axes:
            for suffix, kind in _AXIS_PINS:
                signal_name = f"compd:{axis}.eoffset-{suffix}"
                pin = self.comp.newpin(f"{axis}.eoffset-{suffix}", kind, hal.HAL_OUT)
                if signal_name in signals:
                    # Seed the pin with what the signal holds: linking never steps the offset.
                    pin.set(signals[signal_name]["VALUE"])
                else:
                    _checked(hal.new_sig(signal_name, kind), f"create signal {signal_name}")
                # Always: HAL keeps a link to the same signal quietly, and a signal left
                # over from a refused start may lack it.
                links.append((f"axis.{axis}.eoffset-{suffix}", signal_name))
                links.append((f"{self.name}.{axis}.eoffset-{suffix}", signal_name))
        self.comp.ready()
        for pin_name, signal_name in links:
            _checked(hal.connect(pin_name, signal_name), f"link {pin_name} to {signal_name}")
        for axis in axes:
            self.comp[f"{axis}.eoffset-scale"] = self.scale
            self.comp[f"{axis}.eoffset-enable"] = True
        self.inputs, self.axes = inputs, axes

    @staticmethod
    def _source(address, pins, signals):
        """The signal an input pin links to, and its HAL type (a new ``compd:`` signal for a lone output pin)."""
        item = signals.get(address) or pins.get(address)
        if item is None:
            raise Refused(f"LinuxCNC has no HAL signal or pin named {address!r}")
        kind = _TYPES.get(item["TYPE"])
        if kind is None:
            raise Refused(f"{address} is not a bit, float, s32 or u32: compd cannot read it")
        if address in signals:
            return address, kind
        if item["DIRECTION"] != hal.HAL_OUT:
            raise Refused(
                f"{address} is an input pin: name the signal or output pin that drives it"
            )
        for name, sig in signals.items():
            if sig["DRIVER"] == address:
                return name, kind
        return f"compd:{address}", kind

    def read(self, addresses):
        self.ensure(addresses)
        values = {}
        for address in addresses:
            if _is_axis(address):
                values[address] = float(self.comp[f"{address[5:]}.eoffset-counts"])
            else:
                values[address] = float(self.comp[address])
        return values

    def write(self, counts):
        for address in counts:
            if not _is_axis(address):
                raise Refused(
                    f"{address!r} is not an axis (axis.x, axis.z, ...): it cannot be written"
                )
        self.ensure(list(counts))
        for address, value in counts.items():
            self.comp[f"{address[5:]}.eoffset-counts"] = int(value)

    def _alive(self):
        if not hal.component_exists(self.name):
            raise Refused(f"HAL component {self.name!r} was unloaded", "disconnected")

    def exit(self):
        with contextlib.suppress(Exception):  # already gone with HAL: nothing left to release
            self.comp.exit()


def _is_axis(address):
    return len(address) == 6 and address.startswith("axis.") and address[5] in AXES


def _refuse_foreign_nets(axis):
    """Refuse when the HAL file nets the axis's offset pins itself: compd's offsets would not arrive.

    An IN pin takes one signal; one netted elsewhere (``net compd-z-counts =>
    axis.z.eoffset-counts``) keeps LinuxCNC's offset at 0 and its enable FALSE
    whatever compd's pins hold. hal's Python module does not tell which signal
    a pin is linked to; ``halcmd -s show pin`` does (``... NAME <== SIGNAL``).
    """
    try:
        shown = subprocess.run(
            ["halcmd", "-s", "show", "pin", f"axis.{axis}.eoffset-"],
            capture_output=True,
            text=True,
            timeout=10,
            check=False,
        ).stdout
    except (OSError, subprocess.SubprocessError):
        return  # no halcmd: linking the pins below still fails on a foreign net
    for line in shown.splitlines():
        words = line.split()
        if "<==" not in words:
            continue
        arrow = words.index("<==")
        pin, signal_name = words[arrow - 1], words[arrow + 1]
        suffix = pin.rsplit("-", 1)[-1]
        if suffix in _OWN_SUFFIXES and signal_name != f"compd:{axis}.eoffset-{suffix}":
            raise Refused(
                f"{pin} is netted to HAL signal {signal_name!r} (a net in the HAL file?), so "
                f"the offsets compd writes would never reach axis {axis.upper()}: compd's "
                f"driver nets axis.{axis}.eoffset-counts, -scale and -enable itself; remove "
                f"the HAL file's net and setp lines for these three pins (deploy/README.md, "
                f"LinuxCNC) and restart LinuxCNC"
            )


def _checked(failed, what):
    # hal.connect and hal.new_sig return True when HAL refused (2.9), or raise.
    if failed:
        raise Refused(
            f"HAL refused to {what}: a second writer (another compd with this component's "
            "axes still running?) or a pin already linked to another signal"
        )


def serve(name, lines, out):
    component = None
    try:
        for line in lines:
            reply = _answer(name, line, component)
            if isinstance(reply, Component):
                component, reply = reply, {"ok": None}
            out.write(json.dumps(reply) + "\n")
            out.flush()
            if component is None or reply.get("kind") == "disconnected":
                break  # a failed open, or HAL gone: the driver starts a new helper
    finally:
        if component is not None:
            component.exit()


def _answer(name, line, component):
    """The reply to one request line; for a successful open, the new component."""
    try:
        request = json.loads(line)
        if "open" in request:
            if component is not None:
                raise Refused("already open")
            return Component(name, float(request["open"]["scale"]))
        if component is None:
            raise Refused("not open")
        if "read" in request:
            return {"ok": component.read(request["read"])}
        if "write" in request:
            component.write(request["write"])
            return {"ok": None}
        raise Refused(f"unknown request {line.strip()!r}")
    except Refused as exc:
        error = {"error": str(exc), "kind": exc.kind}
    except Exception as exc:  # a HAL call failing under us: report it, the driver reconnects
        error = {"error": f"{type(exc).__name__}: {exc}", "kind": "disconnected"}
    return error


def main():
    # SIGTERM is how halcmd unloads a userspace component: leave through
    # serve()'s finally, which removes the component.
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
    serve(sys.argv[1], sys.stdin, sys.stdout)


if __name__ == "__main__":
    main()
