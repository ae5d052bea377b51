"""Shared helpers for the benchmarks in bench/: timing, peak memory, machine info, output.

Import this module BEFORE torch (it sets ``TORCHINDUCTOR_COMPILE_THREADS=1``
unless already set, so inductor's compile workers do not compete with the
timed threads on a small CPU machine). The scripts are run as files
(``python bench/sim_throughput.py``), so ``bench/`` is on ``sys.path``.

Method, shared by every benchmark:

* a run of ``steps`` calls is timed as a whole (``CLOCK``: ``time.perf_counter``, with a
  device synchronisation before and after on CUDA; a script may set it to
  ``time.process_time``: the option ``--cpu-time``); ``warmup`` untimed
  calls come first;
* the run is repeated ``repeats`` times; the reported rate is the median of
  the per-run rates, with the min and max as the spread;
* compile time (first call of a compiled function, including its warm-up) is
  measured separately and never enters a rate.
"""

from __future__ import annotations

import ctypes
import gc
import json
import math
import os
import platform
import resource
import statistics
import sys
import time
from dataclasses import dataclass, field
from typing import Any, Callable

os.environ.setdefault("TORCHINDUCTOR_COMPILE_THREADS", "1")

import torch  # noqa: E402

from torchnav.memory import freed_memory_held, hold_freed_memory  # noqa: E402

if "--hold-memory" in sys.argv:  # before the bench allocates anything big (torchnav/memory.py)
    hold_freed_memory()


# -- device and threads -----------------------------------------------------------


def resolve_devices(arg: str) -> list[str]:
    """``--device`` value -> devices to run: ``cpu``, ``cuda``, or ``all`` (cpu, plus cuda if present)."""
    if arg == "all":
        return ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
    if arg.startswith("cuda") and not torch.cuda.is_available():
        raise SystemExit(f"--device {arg}: no CUDA device is available")
    return [arg]


def set_threads(n: int) -> None:
    """Intra-op CPU threads for the timed work (``torch.set_num_threads``)."""
    torch.set_num_threads(n)


def sync(device: str | torch.device) -> None:
    if torch.device(device).type == "cuda":
        torch.cuda.synchronize(device)


def machine_info(device: str) -> dict[str, Any]:
    """A short description of where the figures were taken."""
    info: dict[str, Any] = {
        "python": platform.python_version(),
        "torch": torch.__version__,
        "cpu": _cpu_model(),
        "cpu_count": os.cpu_count(),
        "threads": torch.get_num_threads(),
        "loadavg_1m": round(os.getloadavg()[0], 2) if hasattr(os, "getloadavg") else None,
        "malloc": "held" if freed_memory_held() else "system",
    }
    if torch.device(device).type == "cuda":
        info["gpu"] = torch.cuda.get_device_name(device)
    return info


def print_header(title: str, device: str, log, json_bench: str | None = None) -> dict[str, Any]:
    """``== title``, the machine's line and any load warning on ``log``; with ``json_bench`` also a JSON
    record of the machine. Returns :func:`machine_info`."""
    info = machine_info(device)
    print(f"\n== {title}\n   " + ", ".join(f"{k}={v}" for k, v in info.items()), file=log)
    warn = load_warning(device)
    if warn:
        print(warn, file=log)
    if json_bench:
        emit_json({"bench": json_bench, "device": device, **info})
    return info


def start(args, title: str, device: str, json_bench: str | None = None):
    """Set ``args.threads`` torch threads and print the header (:func:`print_header`); returns the stream
    for tables: stderr with ``--json``, whose stdout then holds only JSON lines. ``--cpu-time`` sets ``CLOCK``."""
    global CLOCK
    set_threads(args.threads)
    if args.cpu_time:
        CLOCK = time.process_time
        title += " (rates in CPU time: --cpu-time)"
    log = sys.stderr if args.json else sys.stdout
    print_header(title, device, log, json_bench if args.json else None)
    return log


def timing_args(p, run_seconds: float, warmup: int = 5) -> None:
    """The timing options every throughput bench takes: ``--threads``, ``--steps``, ``--run-seconds``, ``--repeats``, ``--warmup``,
    ``--cpu-time``, ``--hold-memory``."""
    p.add_argument("--threads", type=int, default=2, help="torch CPU threads (default 2)")
    p.add_argument("--hold-memory", action="store_true",
                   help="torchnav.memory.hold_freed_memory(): glibc malloc serves big blocks from its heap and keeps freed memory "
                        "for reuse (default: malloc as it is, as in the recipes)")
    p.add_argument("--cpu-time", action="store_true",
                   help="time runs in this process's CPU time (time.process_time) instead of wall time: on a shared "
                        "machine, time spent waiting for a core is not counted (meaningful with --threads 1 on CPU)")
    p.add_argument("--steps", type=int, default=0, help="steps per timed run (default: calibrated to --run-seconds)")
    p.add_argument("--run-seconds", type=float, default=run_seconds, help=f"target wall time of one timed run (default {run_seconds:g})")
    p.add_argument("--repeats", type=int, default=5, help="timed runs (collector: timed batches); the median rate is reported (default 5)")
    p.add_argument("--warmup", type=int, default=warmup, help=f"untimed steps before timing (default {warmup})")


def uniform_sampler(g: torch.Generator) -> Callable[..., torch.Tensor]:
    """``u(lo, hi, *shape)``: uniform numbers in ``[lo, hi)`` of that shape, drawn from ``g``."""

    def u(lo: float, hi: float, *shape: int) -> torch.Tensor:
        return lo + (hi - lo) * torch.rand(*shape, generator=g)

    return u


def free_poses(world, radius: float, half: float, edge: float, u: Callable[..., torch.Tensor], tries: int = 200) -> torch.Tensor:
    """Poses ``(B, 3)`` in the free space of a ``[-half, half]^2`` arena, by rejection sampling all envs at
    once: more than ``radius + 0.05`` m from every obstacle and at most ``half - edge`` m from the centre
    along each axis. ``u(lo, hi, *shape)`` draws uniform numbers."""
    from torchnav.sim import disc_clearance

    b = world.batch_size[0]
    pose = torch.stack((u(-half, half, b), u(-half, half, b), u(-math.pi, math.pi, b)), -1)
    for _ in range(tries):
        bad = (disc_clearance(pose, world, radius) <= 0.05) | (pose[:, :2].abs().amax(-1) > half - edge)
        n = int(bad.sum())
        if n == 0:
            return pose
        pose[bad] = torch.stack((u(-half, half, n), u(-half, half, n), u(-math.pi, math.pi, n)), -1)
    raise RuntimeError("could not place every robot in free space")


def random_twists(params, u: Callable[..., torch.Tensor], b: int, n: int = 8) -> list[torch.Tensor]:
    """``n`` batches ``(b, 2)`` of twist commands drawn uniformly within ``params``' speed limits."""
    return [torch.stack((u(params.v_min, params.v_max, b), u(-params.omega_max, params.omega_max, b)), -1) for _ in range(n)]


def load_warning(device: str) -> str | None:
    """A warning line when other processes are busy on this machine, else None.

    Why it matters: with ``--threads`` equal to the number of cores, OpenMP worker
    threads spin-wait after each parallel region; when another process holds a
    core, the spinning worker and the main thread take turns by time slices and
    eager CPU figures collapse (10-100x slower), not just degrade.
    """
    if torch.device(device).type != "cpu" or not hasattr(os, "getloadavg"):
        return None
    load, cpus = os.getloadavg()[0], os.cpu_count() or 1
    if load < 0.5:
        return None
    return (f"   WARNING: 1-min load average {load:.2f} on {cpus} CPUs: other processes are running, so these CPU figures "
            f"are not representative{' (and OpenMP spin-waiting with ' + str(torch.get_num_threads()) + ' threads makes them collapse)' if torch.get_num_threads() >= cpus else ''}")


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


# -- timing -------------------------------------------------------------------------------


@dataclass
class Timing:
    """Rates of ``repeats`` timed runs of ``steps`` calls, each call worth ``items`` units (env-steps)."""

    items_per_call: int
    steps: int
    seconds: list[float] = field(default_factory=list)

    @property
    def rates(self) -> list[float]:
        return [self.items_per_call * self.steps / s for s in self.seconds]

    @property
    def median(self) -> float:
        return statistics.median(self.rates)

    def fields(self) -> dict[str, float]:
        """:func:`rate_fields` of the runs."""
        return rate_fields(self.rates)

    @property
    def call_us(self) -> float:
        """Median wall time of one call in microseconds."""
        return 1e6 * statistics.median(self.seconds) / self.steps


CLOCK = time.perf_counter  # what time_calls measures: wall time by default


def rate_fields(rates: list[float]) -> dict[str, float]:
    """A record's ``env_steps_per_s`` (the median rate), ``env_steps_per_s_min`` and ``env_steps_per_s_max``, rounded."""
    return {"env_steps_per_s": round(statistics.median(rates), 1), "env_steps_per_s_min": round(min(rates), 1),
            "env_steps_per_s_max": round(max(rates), 1)}


def time_calls(
    fn: Callable[[], Any],
    *,
    items_per_call: int,
    steps: int,
    repeats: int,
    warmup: int,
    device: str | torch.device,
) -> Timing:
    """Time ``fn()`` (which carries its own state between calls, e.g. in a closure).

    ``warmup`` untimed calls, then ``repeats`` runs of ``steps`` calls, each run timed
    as a whole with a synchronisation before and after on CUDA.
    """
    for _ in range(warmup):
        fn()
    sync(device)
    t = Timing(items_per_call=items_per_call, steps=steps)
    for _ in range(repeats):
        sync(device)
        t0 = CLOCK()
        for _ in range(steps):
            fn()
        sync(device)
        t.seconds.append(CLOCK() - t0)
    return t


def steps_for(num_envs: int, target_env_steps: float, lo: int, hi: int) -> int:
    """Calls per timed run so that a run covers about ``target_env_steps`` env-steps, within [lo, hi]."""
    return int(max(lo, min(hi, round(target_env_steps / max(num_envs, 1)))))


# -- peak memory -----------------------------------------------------------------------------


def _read_status_kib(key: str) -> int | None:
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith(key + ":"):
                    return int(line.split()[1])
    except OSError:
        pass
    return None


def _malloc_trim() -> None:
    """Give freed heap memory back to the OS (glibc), so the RSS baseline is the live set."""
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass


class PeakMemory:
    """Peak memory of the work done inside a ``with`` block, as an increase over its start.

    * CUDA: ``torch.cuda.max_memory_allocated`` minus ``memory_allocated`` at the start
      (bytes held by tensors; the caching allocator's reserve is not counted).
    * CPU (Linux): the process resident-set high-water mark (``VmHWM``), reset at the
      start by writing 5 to ``/proc/self/clear_refs``, minus the resident set at the
      start (after ``gc.collect`` and ``malloc_trim``). Inputs allocated before the
      block are not counted; temporaries and outputs are. Page granularity, and
      allocator caching can hide reuse, so read it as an approximation.
    * Fallback (no clear_refs): increase of ``getrusage(RUSAGE_SELF).ru_maxrss``,
      which is 0 when an earlier part of the process already went higher.

    After the block, ``bytes`` holds the figure and ``method`` names how it was taken.
    """

    def __init__(self, device: str | torch.device):
        self.device = torch.device(device)
        self.bytes: int = 0
        self.method: str = ""

    def __enter__(self) -> "PeakMemory":
        gc.collect()
        if self.device.type == "cuda":
            sync(self.device)
            torch.cuda.reset_peak_memory_stats(self.device)
            self._base = torch.cuda.memory_allocated(self.device)
            self.method = "cuda_max_memory_allocated_increase"
            return self
        _malloc_trim()
        self._base_rss = _read_status_kib("VmRSS")
        self._hwm_ok = False
        try:
            with open("/proc/self/clear_refs", "w") as f:
                f.write("5")
            self._hwm_ok = self._base_rss is not None and _read_status_kib("VmHWM") is not None
        except OSError:
            pass
        if self._hwm_ok:
            self.method = "cpu_rss_high_water_increase"
        else:
            self._base_maxrss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
            self.method = "cpu_ru_maxrss_increase"
        return self

    def __exit__(self, *exc: Any) -> None:
        if self.device.type == "cuda":
            sync(self.device)
            self.bytes = int(torch.cuda.max_memory_allocated(self.device) - self._base)
        elif self._hwm_ok:
            self.bytes = 1024 * max(0, (_read_status_kib("VmHWM") or 0) - self._base_rss)
        else:
            self.bytes = 1024 * max(0, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - self._base_maxrss)


# -- output ----------------------------------------------------------------------------------


def human_rate(x: float) -> str:
    for unit, scale in (("G", 1e9), ("M", 1e6), ("k", 1e3)):
        if abs(x) >= scale:
            return f"{x / scale:.2f}{unit}"
    return f"{x:.1f}"


def human_bytes(n: float) -> str:
    for unit, scale in (("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if abs(n) >= scale:
            return f"{n / scale:.1f}{unit}"
    return f"{int(n)}B"


def print_table(headers: list[str], rows: list[list[Any]], file=None) -> None:
    """A plain left-aligned text table."""
    file = file or sys.stdout
    cells = [[str(h) for h in headers]] + [[str(c) for c in r] for r in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(headers))]
    for k, r in enumerate(cells):
        print("  ".join(c.rjust(w) if k and _numeric(c) else c.ljust(w) for c, w in zip(r, widths)).rstrip(), file=file)
        if k == 0:
            print("  ".join("-" * w for w in widths), file=file)
    file.flush()


def _numeric(s: str) -> bool:
    return bool(s) and (s[0].isdigit() or s[0] in "-+.") and s not in ("-",)


def emit_json(record: dict[str, Any]) -> None:
    """One JSON object on one line of stdout."""
    print(json.dumps(record, sort_keys=False), flush=True)


def calibrate(call: Callable[[], Any], device: str, run_seconds: float, lo: int, hi: int) -> int:
    """Calls per timed run so that a run lasts about ``run_seconds``."""
    n, dt = 1, 0.0
    while True:
        sync(device)
        t0 = time.perf_counter()
        for _ in range(n):
            call()
        sync(device)
        dt = time.perf_counter() - t0
        if dt >= min(0.05, run_seconds / 4) or n >= hi:
            break
        n *= 2
    return int(max(lo, min(hi, math.ceil(run_seconds * n / max(dt, 1e-9)))))
