"""CPU time of this process between two readings: user and sys, and each thread's (Linux).

For the benchmarks of the loop (:mod:`bench_tick`): a process that wakes ten
times a second spends a fraction of a millisecond per wake-up, so user and
sys come from ``getrusage`` (microseconds; ``os.times`` counts 10 ms clock
ticks; the kernel splits the total between user and sys by sampling, so the
split is approximate and the sum exact) and each thread's time from
``/proc/self/task/*/schedstat`` (nanoseconds).
"""

from __future__ import annotations

import os
import resource
import threading
from dataclasses import dataclass, field


@dataclass(frozen=True)
class CpuReading:
    """The process's user and sys CPU time (s) and each live thread's CPU time (s) by thread id."""

    user_s: float
    sys_s: float
    #: Thread id -> (name, CPU s); empty where ``/proc`` has no per-thread figures.
    threads: dict[int, tuple[str, float]]

    @classmethod
    def now(cls) -> CpuReading:
        usage = resource.getrusage(resource.RUSAGE_SELF)  # us resolution (os.times: 10 ms)
        return cls(usage.ru_utime, usage.ru_stime, thread_cpu_s())


@dataclass(frozen=True)
class CpuPerTick:
    """CPU ms per tick between two readings: user, sys, and each thread's (name -> ms)."""

    user_ms: float
    sys_ms: float
    threads_ms: dict[str, float] = field(default_factory=dict)

    @property
    def total_ms(self) -> float:
        return self.user_ms + self.sys_ms

    @classmethod
    def between(cls, start: CpuReading, end: CpuReading, ticks: int) -> CpuPerTick:
        """Per tick over ``ticks``; a thread started after ``start`` counts from zero."""
        threads: dict[str, float] = {}
        for tid, (name, cpu_s) in end.threads.items():
            before_s = start.threads.get(tid, (name, 0.0))[1]
            key = name if name not in threads else f"{name} ({tid})"
            threads[key] = (cpu_s - before_s) * 1e3 / ticks
        return cls(
            (end.user_s - start.user_s) * 1e3 / ticks,
            (end.sys_s - start.sys_s) * 1e3 / ticks,
            threads,
        )

    def __str__(self) -> str:
        return f"{self.total_ms:.3f} ms (user {self.user_ms:.3f} + sys {self.sys_ms:.3f})"

    def per_thread(self) -> str:
        """``MainThread 0.812, compd-recorder 0.001`` (ms per tick); threads idle throughout left out."""
        busy = [(ms, name) for name, ms in self.threads_ms.items() if ms >= 0.0005]
        return ", ".join(f"{name} {ms:.3f}" for ms, name in sorted(busy, reverse=True)) or "n/a"


def thread_cpu_s() -> dict[int, tuple[str, float]]:
    """Each thread's CPU time so far (s, ns resolution from ``schedstat``), named as Python names it."""
    names = {t.native_id: t.name for t in threading.enumerate()}
    threads = {}
    try:
        tids = os.listdir("/proc/self/task")
    except OSError:  # not Linux: process figures only
        return {}
    for tid_text in tids:
        tid = int(tid_text)
        try:
            with open(f"/proc/self/task/{tid}/schedstat") as f:
                on_cpu_ns = int(f.read().split()[0])
        except (OSError, ValueError, IndexError):  # the thread ended meanwhile
            continue
        threads[tid] = (names.get(tid, f"thread {tid}"), on_cpu_ns / 1e9)
    return threads
