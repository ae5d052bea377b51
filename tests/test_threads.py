"""The recipes' thread governor: fewer torch threads while another process keeps a core busy."""

import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "recipes"))
import builders as B  # noqa: E402

needs_proc_stat = pytest.mark.skipif(not Path("/proc/stat").is_file(), reason="auto threads read /proc/stat (Linux)")


def test_fixed_and_invalid_settings():
    before = torch.get_num_threads()
    try:
        g = B.ThreadGovernor(1)
        assert g.threads == 1 and not g.auto and torch.get_num_threads() == 1
        assert g.update(force=True) is None  # a fixed count never changes
        for bad in ("x", 0, -2, 1.5, True):
            with pytest.raises(B.ConfigError, match="threads=.*: must be 'auto' or an int >= 1"):
                B.ThreadGovernor(bad)
    finally:
        torch.set_num_threads(before)


def _auto_governor_on_an_idle_machine() -> B.ThreadGovernor:
    """An ``auto`` governor, or a skip where the machine cannot show what it does (one core, a
    container whose /proc/stat counts other cores, other processes already busy, or other test
    processes of this run beside it, which may get busy at any moment)."""
    from conftest import alone_on_the_machine

    if not alone_on_the_machine():
        pytest.skip("needs the machine to itself, not beside other test processes: python -m pytest -n 0 tests/test_threads.py")
    g = B.ThreadGovernor("auto", interval=0.5)
    if not g.auto or g.cores < 2:
        pytest.skip("needs 2 or more cores counted alike by /proc/stat and the affinity mask")
    mark = g._sample()
    time.sleep(1.0)
    if g.others(mark, g._sample()) > 0.3:  # the governor would rightly keep a core free for that work
        pytest.skip("other processes already keep a core busy: the test needs a machine this test has to itself")
    return g


@needs_proc_stat
def test_auto_gives_a_core_to_a_busy_process_and_takes_it_back():
    before = torch.get_num_threads()
    try:
        g = _auto_governor_on_an_idle_machine()
        others = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(g.cores - 1)]
        try:
            time.sleep(1.5)  # let them start
            g._mark = g._sample()
            time.sleep(1.0)
            g.update()
            assert g.threads == 1 and torch.get_num_threads() == 1, g.changes
        finally:
            for p in others:
                p.kill()
                p.wait()
        time.sleep(0.2)
        g._mark = g._sample()
        time.sleep(1.0)
        g.update()
        assert g.threads == g.cores, g.changes
        assert [c[1] for c in g.changes][-2:] == [1, g.cores]
    finally:
        torch.set_num_threads(before)


def test_threads_arg():
    assert B.threads_arg("auto") == "auto" and B.threads_arg("3") == 3
    import argparse

    for bad in ("0", "-1", "two"):
        with pytest.raises(argparse.ArgumentTypeError):
            B.threads_arg(bad)


@needs_proc_stat
def test_auto_counts_its_own_finished_children_as_its_own_work():
    # torch.compile runs C++ compilers as child processes; their CPU time is this run's, so a
    # compile must not make the governor give a core away.
    before = torch.get_num_threads()
    try:
        g = _auto_governor_on_an_idle_machine()
        g._mark = g._sample()
        subprocess.run([sys.executable, "-c", "import time\nt = time.process_time()\nwhile time.process_time() - t < 1.0: pass"], check=True)
        now = g._sample()
        assert g.others(g._mark, now) < 0.3, "a finished child's CPU time was counted as another process's"
        g.update(force=True)
        assert g.threads == g.cores, g.changes
    finally:
        torch.set_num_threads(before)


def test_steal_is_read_and_reported_as_part_of_the_others(tmp_path):
    """Hypervisor steal (the 8th column of /proc/stat's cpu line) counts as busy time that is not this
    process's; the governor reports its share, so a drop to fewer threads on an otherwise idle VM
    can be told from another process."""
    before = torch.get_num_threads()
    try:
        g = B.ThreadGovernor(1)
        stat = tmp_path / "stat"
        g.STAT = stat
        tick = B.os.sysconf("SC_CLK_TCK")
        stat.write_text("cpu  1000 0 100 5000 10 0 0 300 0 0\ncpu0 1 0 0 0 0 0 0 0 0 0\n")
        a = g._sample()
        stat.write_text(f"cpu  1000 0 100 5000 10 0 0 {300 + 2 * tick} 0 0\ncpu0 1 0 0 0 0 0 0 0 0 0\n")
        b = g._sample()
        assert a[3] == pytest.approx(300 / tick) and b[1] - a[1] == pytest.approx(2.0)  # steal is inside busy
        late = (a[0] + 4.0, *b[1:])  # as if 4 s had passed: 2 s of steal is half a core, all of it "others"
        assert g.stolen(a, late) == pytest.approx(0.5) and g.others(a, late) == pytest.approx(0.5, abs=0.05)
    finally:
        torch.set_num_threads(before)
