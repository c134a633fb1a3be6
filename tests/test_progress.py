"""The shared progress rule (warpcoil.progress): bar on a terminal, lines in a log, nothing when quiet."""

import io

from warpcoil import progress as progress_module
from warpcoil.progress import Progress


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_a_log_gets_a_line_per_tenth_and_one_at_the_end(monkeypatch):
    monkeypatch.setattr(progress_module, "LINE_INTERVAL_S", 1e9)  # only the 10 % steps
    log = io.StringIO()
    bar = Progress("deployed", "mm", total=50.0, stream=log)
    for k in range(1, 501):
        bar.update(k * 0.1, note=f"push {k}")
    bar.close()
    lines = log.getvalue().splitlines()
    assert "\r" not in log.getvalue()
    assert len(lines) == 10  # 10 %, 20 %, … 100 %; close() does not repeat the last
    assert lines[0].startswith("deployed 5.0/50.0 mm (10 %), push 50 [")
    assert lines[-1].startswith("deployed 50.0/50.0 mm (100 %), push 500 [")


def test_a_log_gets_a_line_every_interval_without_steps(monkeypatch):
    now = [0.0]
    monkeypatch.setattr(progress_module.time, "monotonic", lambda: now[0])
    log = io.StringIO()
    bar = Progress("sweep", "deployments", stream=log, decimals=0)  # total unknown: no percent steps
    for done in range(6):
        now[0] += 4.0  # 4 s per deployment
        bar.update(done)
    bar.close()
    assert log.getvalue().splitlines() == ["sweep 2/? deployments [12 s]",  # the first ≥ 10 s after the start
                                           "sweep 5/? deployments [24 s]"]  # 12 s later; close() adds nothing new


def test_quiet_prints_nothing_and_a_terminal_gets_a_bar():
    log = io.StringIO()
    quiet = Progress("deployed", "mm", total=10.0, quiet=True, stream=log)
    quiet.update(5.0)
    quiet.close()
    assert log.getvalue() == ""
    terminal = Terminal()
    bar = Progress("sweep", "deployments", stream=terminal, decimals=0)
    bar.update(1, total=2)  # the total may come later (a sweep learns it on its first report)
    bar.update(2)
    bar.close()
    assert "\r" in terminal.getvalue() and "2/2 deployments" in terminal.getvalue()


def test_a_terminal_bar_is_redrawn_at_most_every_interval_and_ends_on_the_last_update(monkeypatch):
    now = [0.0]
    monkeypatch.setattr(progress_module.time, "monotonic", lambda: now[0])
    terminal = Terminal()
    bar = Progress("deployed", "mm", total=10.0, stream=terminal)
    for k in range(1, 101):  # a frame every 10 ms: 10 redraws in the second, not 100
        now[0] += 0.01
        bar.update(0.1 * k, note=f"push {k}")
    drawn = [part for part in terminal.getvalue().split("\r") if part.startswith("deployed")]
    bar.close()
    assert 10 <= len(drawn) <= 12  # (tqdm's own first draw, then one per BAR_INTERVAL_S)
    assert terminal.getvalue().rstrip().endswith("push 100")
    assert "10.0/10.0 mm" in terminal.getvalue().split("\r")[-1]
