"""Progress lines for logs (scanloc.progress): readable durations, an honest time to go."""

from __future__ import annotations

from scanloc.progress import duration, step_line, steps


def test_durations_read_at_a_glance() -> None:
    assert [duration(s) for s in (0.4, 59, 61, 3599, 3720)] == [
        "0 s",
        "59 s",
        "1 min 01 s",
        "59 min 59 s",
        "1 h 02 min",
    ]


def test_step_line_extrapolates_the_mean_step_time() -> None:
    line = step_line("epoch", 2, 5, 60.0, {"val_mae": "0.123"})
    assert line == "epoch 2/5: val_mae 0.123 (1 min 00 s elapsed, ~1 min 30 s to go)"
    assert step_line("scans", 10, 10, 5.0) == "scans 10/10 (5 s elapsed)"


def test_steps_prints_a_line_per_item_off_a_terminal(capsys) -> None:
    assert list(steps(["amcl", "hybrid"], "localize drive")) == ["amcl", "hybrid"]
    assert capsys.readouterr().err.splitlines() == [
        "localize drive: amcl",
        "localize drive: hybrid",
    ]
