"""A user's mistake is one message and exit status 2, never a traceback unless asked for
(scanloc.stages._app); a bug keeps its traceback."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from scanloc.stages._app import USER_ERROR_STATUS, reporting_user_errors

REPO_ROOT = Path(__file__).resolve().parents[1]


def fails_with(err: BaseException):
    def main() -> None:
        raise err

    return main


def test_a_users_mistake_is_its_message_and_status_2(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("SCANLOC_TRACEBACK", raising=False)
    bad = fails_with(ValueError("office.yaml: field 'resolution': expected > 0, got -1"))
    with pytest.raises(SystemExit) as stopped:
        reporting_user_errors("scanloc.stages.maps", bad)()
    assert stopped.value.code == USER_ERROR_STATUS == 2
    err = capsys.readouterr().err
    assert err.startswith(
        "scanloc.stages.maps: error: office.yaml: field 'resolution': expected > 0, got -1\n"
    )
    with pytest.raises(SystemExit):
        reporting_user_errors("x", fails_with(FileNotFoundError("/data/map.yaml: not found")))()


def test_scanloc_traceback_shows_it_and_a_bug_keeps_it(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("SCANLOC_TRACEBACK", "1")
    with pytest.raises(ValueError, match="field 'resolution'"):
        reporting_user_errors("x", fails_with(ValueError("field 'resolution'")))()
    monkeypatch.delenv("SCANLOC_TRACEBACK")
    with pytest.raises(ZeroDivisionError):
        reporting_user_errors("x", fails_with(ZeroDivisionError("a bug")))()


def test_a_missing_setting_names_the_field_without_a_traceback(tmp_path: Path) -> None:
    env = {k: v for k, v in os.environ.items() if k not in ("SCANLOC_TRACEBACK", "DVC_STAGE")}
    done = subprocess.run(
        [sys.executable, "-m", "scanloc.stages.bag", "name=office", f"hydra.run.dir={tmp_path}"],
        cwd=REPO_ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 2
    assert "scanloc.stages.bag: error: config field 'bag': expected a value (give bag=...)" in (
        done.stderr
    )
    assert "Traceback" not in done.stderr
