"""``python -m imm_gym.evaluate --ray`` checks its arguments, configuration and policies before it
joins Ray: a refused command starts no Ray and no shard actor.

The joining (``imm_gym.evaluation.distributed.connect``) is replaced by a recorder: these tests
start no Ray.
"""

from __future__ import annotations

import socket

import pytest

# ray.rllib, not ray: with tests/ on the path this very directory imports as a namespace "ray"
pytest.importorskip("ray.rllib")

from imm_gym.cli.evaluate import main
from imm_gym.evaluation import distributed

pytestmark = pytest.mark.ray


@pytest.fixture
def joins(monkeypatch: pytest.MonkeyPatch) -> list[str | None]:
    """The addresses ``--ray`` joins (each raises the ConnectionError of an address with no
    Ray)."""
    calls: list[str | None] = []

    def connect(address: str | None) -> None:
        calls.append(address)
        raise ConnectionError("Could not find any running Ray instance.")

    monkeypatch.setattr(distributed, "connect", connect)
    return calls


@pytest.mark.parametrize(
    ("argv", "named"),
    [
        (["--policy", "no-such-policy"], "unknown policy 'no-such-policy'"),
        (["--policy", "fixed", "--bank", "no-such-bank"], "--bank must be one of"),
        (["--policy", "fixed", "--reference", "tip-imm"], "--reference 'tip-imm'"),
        (["--policy", "fixed", "--suite", "no-such-suite"], "no-such-suite"),
    ],
    ids=["policy", "bank", "reference", "suite"],
)
def test_a_refused_command_does_not_join_ray(argv, named, joins, capsys):
    with pytest.raises(SystemExit) as exc:
        main([*argv, "--runs", "2", "--quiet", "--ray", "auto"])
    assert exc.value.code == 2 and named in capsys.readouterr().err
    assert joins == []


def test_a_cluster_that_cannot_be_joined_is_a_usage_error_naming_ray(joins, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--policy", "fixed", "--runs", "2", "--quiet", "--no-clairvoyant", "--ray", "auto"])
    assert exc.value.code == 2 and "--ray auto: Could not find any running Ray instance" in (
        capsys.readouterr().err
    )
    assert joins == ["auto"]


def test_an_address_where_nothing_listens_is_refused_in_seconds_without_asking_ray(
    monkeypatch, capsys
):
    import ray

    inits: list[dict] = []
    monkeypatch.setattr(ray, "is_initialized", lambda: False)
    monkeypatch.setattr(ray, "init", lambda **kwargs: inits.append(kwargs))
    with socket.socket() as s:  # a port nothing listens on: Ray would retry it for minutes
        s.bind(("127.0.0.1", 0))
        address = f"127.0.0.1:{s.getsockname()[1]}"
    with pytest.raises(SystemExit) as exc:
        main(["--policy", "fixed", "--runs", "2", "--quiet", "--no-clairvoyant", "--ray",
              address])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and f"--ray {address}: nothing answers at {address}" in err
    assert inits == []


def test_a_ray_address_in_the_environment_where_nothing_listens_is_refused_too(
    monkeypatch, capsys
):
    import ray

    inits: list[dict] = []
    monkeypatch.setattr(ray, "is_initialized", lambda: False)
    monkeypatch.setattr(ray, "init", lambda **kwargs: inits.append(kwargs))
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        address = f"127.0.0.1:{s.getsockname()[1]}"
    monkeypatch.setenv("RAY_ADDRESS", address)
    with pytest.raises(SystemExit) as exc:
        main(["--policy", "fixed", "--runs", "2", "--quiet", "--no-clairvoyant", "--ray"])
    assert exc.value.code == 2 and f"nothing answers at {address}" in capsys.readouterr().err
    assert inits == []


def dead_address() -> str:
    """A ``HOST:PORT`` nothing listens on: Ray would retry it for minutes."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"127.0.0.1:{s.getsockname()[1]}"


@pytest.fixture
def inits(monkeypatch: pytest.MonkeyPatch) -> list[dict]:
    """The calls of ``ray.init`` (recorded, none made), with neither ``RAY_ADDRESS`` nor a
    ``ray_current_cluster`` file of an earlier ``ray start`` on this machine."""
    import ray
    import ray._private.utils

    calls: list[dict] = []
    monkeypatch.setattr(ray, "is_initialized", lambda: False)
    monkeypatch.setattr(ray, "init", lambda **kwargs: calls.append(kwargs))
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    monkeypatch.setattr(ray._private.utils, "read_ray_address", lambda temp_dir=None: None)
    return calls


def test_ray_auto_checks_the_ray_address_in_the_environment(inits, monkeypatch, capsys):
    address = dead_address()
    monkeypatch.setenv("RAY_ADDRESS", address)
    with pytest.raises(SystemExit) as exc:
        main(["--policy", "fixed", "--runs", "2", "--quiet", "--no-clairvoyant", "--ray", "auto"])
    err = capsys.readouterr().err
    assert exc.value.code == 2
    assert f"--ray auto: RAY_ADDRESS: nothing answers at {address} within 5 s" in err
    assert inits == []


@pytest.mark.parametrize("flag", [[], ["auto"]], ids=["bare", "auto"])
def test_a_dead_address_left_by_an_earlier_ray_start_is_refused(flag, inits, monkeypatch, capsys):
    import ray._private.utils

    address = dead_address()
    monkeypatch.setattr(ray._private.utils, "read_ray_address", lambda temp_dir=None: address)
    with pytest.raises(SystemExit) as exc:
        main(["--policy", "fixed", "--runs", "2", "--quiet", "--no-clairvoyant", "--ray", *flag])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "ray_current_cluster (left by a `ray start`" in err
    assert f"nothing answers at {address} within 5 s" in err
    assert inits == []


@pytest.mark.parametrize("address", [None, "auto"])
def test_ray_default_without_an_address_to_check_is_left_to_ray(address, inits):
    """Neither ``RAY_ADDRESS`` nor a recorded cluster: Ray finds a local one or starts one."""
    distributed.connect(address)
    assert inits == [{"address": address, "include_dashboard": False, "log_to_driver": False}]
