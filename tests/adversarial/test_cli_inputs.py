"""Bad inputs to ``python -m imm_gym.evaluate``: a usage error (exit 2) naming the flag, the file
and what is wrong, before any evaluation runs; one test per kind of input."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

import imm_gym.cli.evaluate as cli
from imm_gym.cli.arguments import output_problem
from imm_gym.cli.comparison import load_source
from imm_gym.validation import ConfigError


@pytest.fixture
def no_evaluation(monkeypatch: pytest.MonkeyPatch) -> list[object]:
    """Replace the evaluations by a recorder: a test asserts nothing was evaluated."""
    calls: list[object] = []

    def record(*args: object, **kwargs: object) -> None:
        calls.append(args)
        raise AssertionError("evaluated despite a bad argument")

    monkeypatch.setattr(cli, "evaluate", record)
    monkeypatch.setattr("imm_gym.papers.tuned_comparison.evaluate_system", record)
    return calls


def usage_error(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    with pytest.raises(SystemExit) as exc:
        cli.main([*argv, "--quiet"])
    assert exc.value.code == 2
    return capsys.readouterr().err


# --- output paths, checked first ----------------------------------------------------------------


def test_json_output_that_is_a_directory(tmp_path, capsys, no_evaluation) -> None:
    err = usage_error(["--policy", "fixed", "--json", str(tmp_path)], capsys)
    assert f"--json '{tmp_path}': is a directory" in err
    assert no_evaluation == []


def test_json_output_under_a_file(tmp_path, capsys, no_evaluation) -> None:
    (tmp_path / "file").write_text("")
    out = tmp_path / "file" / "sub" / "res.json"
    for scenario in ("paper", "seed003"):
        err = usage_error(["--policy", "fixed", "--scenario", scenario, "--json", str(out)], capsys)
        assert f"--json '{out}': {tmp_path / 'file'} is not a directory" in err
    assert no_evaluation == []


def test_plots_directory_that_is_a_file(tmp_path, capsys, no_evaluation) -> None:
    figs = tmp_path / "figs.png"
    figs.write_text("")
    err = usage_error(["--policy", "fixed", "--plots", str(figs)], capsys)
    assert f"--plots '{figs}': exists and is not a directory" in err
    assert no_evaluation == []


def test_output_in_an_unwritable_place(tmp_path, capsys, no_evaluation) -> None:
    if os.geteuid() == 0:  # root writes through permissions: use a directory nobody writes in
        place = Path("/proc")
        if not place.is_dir():
            pytest.skip("no unwritable directory for root")
    else:
        place = tmp_path / "ro"
        place.mkdir()
        place.chmod(0o555)
    err = usage_error(["--policy", "fixed", "--json", str(place / "new" / "res.json")], capsys)
    assert f"cannot write in {place}" in err
    err = usage_error(["--policy", "fixed", "--plots", str(place / "figs")], capsys)
    assert f"--plots '{place / 'figs'}': cannot write in {place}" in err
    assert no_evaluation == []


def test_outputs_in_new_directories_are_accepted(tmp_path) -> None:
    out, figs = tmp_path / "a" / "b" / "res.json", tmp_path / "c" / "figs"
    assert output_problem(out, "file") is None
    assert output_problem(figs, "directory") is None
    assert not (tmp_path / "a").exists() and not (tmp_path / "c").exists()  # nothing created


def test_an_existing_file_that_cannot_be_written_is_refused(tmp_path, monkeypatch) -> None:
    """The permission is asked of the file itself (root would write through its bits: os.access
    answers as for a user whom they stop); its directory being writable does not do."""
    out = tmp_path / "res.json"
    out.write_text("{}")
    access = os.access
    asked: list[tuple[Path, int]] = []

    def no_write(path: object, mode: int, *args: object, **kwargs: object) -> bool:
        asked.append((Path(path), mode))
        return mode != os.W_OK and access(path, mode, *args, **kwargs)

    monkeypatch.setattr(os, "access", no_write)
    assert output_problem(out, "file") == "is not writable"
    assert (out, os.W_OK) in asked
    assert output_problem(tmp_path / "new.json", "file") is None  # a new file: its directory's
    assert out.read_text() == "{}"


def test_the_write_test_of_an_existing_directory_is_made_in_it(tmp_path, monkeypatch) -> None:
    """An existing output directory is tried by a temporary file in it, not in its parent: an
    unwritable directory in a writable parent is refused, a writable one in an unwritable parent
    taken (``tempfile.TemporaryFile`` stands in for the permission bits root ignores)."""
    import errno
    import tempfile

    temporary = tempfile.TemporaryFile
    locked: list[Path] = []
    tried: list[Path] = []

    def temporary_file(*args: object, dir: object = None, **kwargs: object) -> object:
        tried.append(Path(dir))
        if Path(dir) in locked:
            raise PermissionError(errno.EACCES, "Permission denied")
        return temporary(*args, dir=dir, **kwargs)

    monkeypatch.setattr(tempfile, "TemporaryFile", temporary_file)
    figs = tmp_path / "figs"
    figs.mkdir()
    locked[:] = [figs]
    assert output_problem(figs, "directory") == f"cannot write in {figs} (Permission denied)"
    assert tried == [figs]
    locked[:] = [tmp_path]
    assert output_problem(figs, "directory") is None
    assert output_problem(figs / "new", "directory") is None  # the nearest existing ancestor
    assert "Permission denied" in output_problem(tmp_path / "other", "directory")


# --- one run --------------------------------------------------------------------------------------


def test_one_run_has_no_confidence_interval(tmp_path, capsys) -> None:
    out = tmp_path / "res.json"
    argv = ["--policy", "fixed", "--policy", "tip-imm", "--runs", "1", "--json", str(out)]
    assert cli.main([*argv, "--quiet", "--no-clairvoyant"]) == 0
    d = json.loads(out.read_text())["paired"]["differences"]["tip-imm"]
    assert d["low"] is None and d["high"] is None and isinstance(d["diff"], float)
    assert "undefined (1 run)" in capsys.readouterr().out


# --- scenario files ------------------------------------------------------------------------------


def scenario_error(tmp_path: Path, content: object, capsys) -> tuple[str, str]:
    path = tmp_path / "scen.json"
    path.write_text(content if isinstance(content, str) else json.dumps(content))
    with pytest.raises(ConfigError) as exc:
        load_source(str(path))
    assert str(exc.value).startswith(f"scenario file {path}: ")
    err = usage_error(["--policy", "fixed", "--scenario", str(path)], capsys)
    assert f"scenario file {path}: " in err
    return str(exc.value), err


def test_scenario_file_without_segments(tmp_path, capsys, no_evaluation) -> None:
    message, _ = scenario_error(tmp_path, {"position": [0, 0]}, capsys)
    assert "missing key(s) ['segments']" in message
    assert no_evaluation == []


def test_scenario_file_with_an_unknown_key(tmp_path, capsys, no_evaluation) -> None:
    message, _ = scenario_error(tmp_path, {"segments": [{"duration": 5}], "speed": 3}, capsys)
    assert "unknown key(s) ['speed']" in message


@pytest.mark.parametrize(
    ("content", "named"),
    [
        ({"segments": 5}, "scenario.segments must be a list, got 5 (int)"),
        ({"segments": "abc"}, "scenario.segments must be a list, got 'abc' (str)"),
        ({"segments": [[40, 0.0]]}, "scenario.segments[0] must be a mapping or a Segment"),
        ({"segments": [{"duration": 5}], "position": "ab"}, "scenario.position must be a list"),
        ({"segments": [{"duration": 5}], "T": "1"}, "scenario.T must be a real number"),
        ({"segments": [{"duration": 5, "accel": None}]}, "segment.accel must be a finite real"),
    ],
)
def test_scenario_file_with_a_wrong_type(tmp_path, capsys, no_evaluation, content, named) -> None:
    message, _ = scenario_error(tmp_path, content, capsys)
    assert named in message


@pytest.mark.parametrize("duration", ["x", "40", 40.5, True, None])
def test_scenario_file_with_a_bad_duration(tmp_path, capsys, no_evaluation, duration) -> None:
    content = {"segments": [{"duration": 10}, {"duration": duration}]}
    message, _ = scenario_error(tmp_path, content, capsys)
    assert (
        f"scenario.segments[1]: segment.duration must be an integer in [1, inf), got {duration!r}"
        in message
    )


def test_scenario_file_that_is_not_an_object(tmp_path, capsys, no_evaluation) -> None:
    message, _ = scenario_error(tmp_path, [{"duration": 5}], capsys)
    assert "scenario must be a mapping or a Scenario, got list" in message


def test_scenario_file_that_is_not_json(tmp_path, capsys, no_evaluation) -> None:
    message, _ = scenario_error(tmp_path, "segments: [", capsys)
    assert "not valid JSON" in message


def test_scenario_file_nested_too_deeply(tmp_path, capsys, no_evaluation) -> None:
    message, _ = scenario_error(tmp_path, "[" * 5000 + "]" * 5000, capsys)
    assert "not valid JSON (nested too deeply)" in message


def test_scenario_file_with_integral_float_durations_is_evaluated(tmp_path) -> None:
    path = tmp_path / "scen.json"
    path.write_text(json.dumps({"segments": [{"duration": 30.0}, {"duration": 20}]}))
    scenario = load_source(str(path))
    assert scenario.horizon == 50 and type(scenario.segments[0].duration) is int
    assert cli.main(["--policy", "fixed", "--scenario", str(path), "--runs", "2", "--quiet"]) == 0


# --- other arguments (already rejected before this pass; kept as kinds) ---------------------------


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--policy", "nope"], "unknown policy 'nope'"),
        (["--policy", "fixed", "--runs", "0"], "--runs must be >= 1, got 0"),
        (["--policy", "fixed", "--seed", "-3"], "--seed must be >= 0, got -3"),
        (["--policy", "fixed", "--scenario", "nowhere.json"], "'nowhere.json' is neither"),
        (["--policy", "fixed", "--bank", "huge"], "--bank must be one of"),
        (["--policy", "fixed", "--scenario", "seed003", "--tuned", "bbsca"], "--tuned must be"),
        (["--policy", "fixed", "--runs", "two"], "--runs: invalid int value: 'two'"),
    ],
    ids=["policy", "runs", "seed", "scenario", "bank", "tuned", "runs-type"],
)
def test_other_bad_arguments(argv, message, capsys) -> None:
    assert message in usage_error(argv, capsys)
