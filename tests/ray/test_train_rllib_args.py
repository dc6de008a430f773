"""``train.py --engine rllib`` refuses bad arguments before it connects to Ray or makes a run
directory: a refused run leaves nothing that blocks its rerun ("--out ... already holds").

Ray's ``init`` is replaced by a recorder: these tests start no Ray.
"""

from __future__ import annotations

import socket
from pathlib import Path

import pytest

# ray.rllib, not ray: with tests/ on the path this very directory imports as a namespace "ray"
pytest.importorskip("ray.rllib")
import ray
import ray._private.utils

import train

pytestmark = pytest.mark.ray


@pytest.fixture
def ray_init(monkeypatch: pytest.MonkeyPatch) -> list[dict]:
    """The calls of ``ray.init`` (each raises the ConnectionError of an address with no Ray)."""
    calls: list[dict] = []

    def init(**kwargs) -> None:
        calls.append(kwargs)
        raise ConnectionError(
            "Could not find any running Ray instance. Please specify the one to connect to by "
            "setting `--address` flag or `RAY_ADDRESS` environment variable."
        )

    monkeypatch.setattr(ray, "is_initialized", lambda: False)
    monkeypatch.setattr(ray, "init", init)
    # no RAY_ADDRESS and no cluster recorded by an earlier `ray start` on this machine
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    monkeypatch.setattr(ray._private.utils, "read_ray_address", lambda temp_dir=None: None)
    return calls


def run(tmp_path: Path, config: str, *extra: str) -> int:
    """``train.main`` with ``--engine rllib``, the hyperparameters ``config`` (YAML text) and
    ``--out tmp_path/run``."""
    file = tmp_path / "params.yml"
    file.write_text(config)
    argv = ["--engine", "rllib", "--config", str(file), "--timesteps", "600", "--no-eval"]
    return train.main([*argv, "--no-progress", "--out", str(tmp_path / "run"), *extra])


@pytest.mark.parametrize(
    ("config", "named"),
    [
        ("target_kl: 0.02\n", "target_kl"),
        # 16 x 8 samples an iteration, below the default entry's minibatch: RLlib's own check
        ("n_envs: 8\nn_steps: 16\n", "batch_size"),
    ],
    ids=["no-equivalent", "minibatch-above-iteration"],
)
def test_refused_hyperparameters_leave_no_run_directory_and_start_no_ray(
    config, named, tmp_path, ray_init, capsys
):
    with pytest.raises(SystemExit) as exc:
        run(tmp_path, config)
    assert exc.value.code == 2 and named in capsys.readouterr().err
    assert not (tmp_path / "run").exists() and ray_init == []


def test_a_minibatch_of_every_runners_samples_is_refused_only_with_fewer_runners(
    tmp_path, ray_init, capsys
):
    config = "n_envs: 8\nn_steps: 16\nbatch_size: 256\n"  # two runners' 2 x 128 samples
    with pytest.raises(SystemExit):
        run(tmp_path, config, "--env-runners", "1")
    assert "--env-runners 1" in capsys.readouterr().err and ray_init == []
    with pytest.raises(SystemExit):
        run(tmp_path, config, "--env-runners", "2")
    assert len(ray_init) == 1  # accepted: on to connecting


def test_an_address_ray_cannot_connect_to_is_a_usage_error_before_any_directory(
    tmp_path, ray_init, capsys
):
    with pytest.raises(SystemExit) as exc:
        run(tmp_path, "n_envs: 8\nn_steps: 16\nbatch_size: 64\n", "--ray-address", "auto")
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "--ray-address 'auto': cannot connect to Ray" in err
    assert ray_init == [{"address": "auto", "include_dashboard": False, "log_to_driver": False}]
    assert not (tmp_path / "run").exists()


def test_an_address_where_nothing_listens_is_refused_in_seconds_without_asking_ray(
    tmp_path, ray_init, capsys
):
    with socket.socket() as s:  # a port nothing listens on: Ray would retry it for minutes
        s.bind(("127.0.0.1", 0))
        address = f"127.0.0.1:{s.getsockname()[1]}"
    with pytest.raises(SystemExit) as exc:
        run(tmp_path, "n_envs: 8\nn_steps: 16\nbatch_size: 64\n", "--ray-address", address)
    err = capsys.readouterr().err
    assert exc.value.code == 2 and f"--ray-address {address!r}: cannot connect to Ray" in err
    assert f"nothing answers at {address} within 5 s" in err
    assert ray_init == [] and not (tmp_path / "run").exists()


@pytest.mark.parametrize("given", [["--ray-address", "auto"], []], ids=["auto", "none"])
def test_a_dead_ray_address_in_the_environment_is_refused_in_seconds(
    tmp_path, ray_init, capsys, monkeypatch, given
):
    """``auto`` and no address join what ``RAY_ADDRESS`` names: checked first, and with no
    address the error is that address, not "cannot start a local Ray instance"."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        address = f"127.0.0.1:{s.getsockname()[1]}"
    monkeypatch.setenv("RAY_ADDRESS", address)
    with pytest.raises(SystemExit) as exc:
        run(tmp_path, "n_envs: 8\nn_steps: 16\nbatch_size: 64\n", *given)
    err = capsys.readouterr().err
    prefix = "--ray-address 'auto': " if given else ""
    assert exc.value.code == 2 and f"{prefix}cannot connect to Ray" in err
    assert f"RAY_ADDRESS: nothing answers at {address} within 5 s" in err
    assert "local Ray instance" not in err
    assert ray_init == [] and not (tmp_path / "run").exists()
