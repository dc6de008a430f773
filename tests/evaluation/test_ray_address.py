"""``distributed.unreachable``: an address with nothing listening is told in seconds (Ray itself
retries it for minutes), one with a listener or without a port is left to Ray."""

from __future__ import annotations

import socket
import time

import pytest

from imm_gym.evaluation.distributed import unreachable


def closed_port() -> int:
    """A local port nothing listens on (bound, then released)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_a_listening_port_is_reachable_in_each_form() -> None:
    with socket.create_server(("127.0.0.1", 0)) as server:
        port = server.getsockname()[1]
        assert unreachable(f"127.0.0.1:{port}") is None
        assert unreachable(f"ray://127.0.0.1:{port}") is None
        assert unreachable(f"localhost:{port}") is None


def test_a_port_nothing_listens_on_is_told_at_once() -> None:
    port = closed_port()
    start = time.monotonic()
    reason = unreachable(f"127.0.0.1:{port}", timeout=2.0)
    assert reason is not None and f"nothing answers at 127.0.0.1:{port} within 2 s" in reason
    assert time.monotonic() - start < 2.5
    assert unreachable(f"ray://127.0.0.1:{port}") is not None


@pytest.mark.parametrize("address", [None, "auto", "local", "http://127.0.0.1:8265"])
def test_an_address_without_a_port_of_its_own_is_left_to_ray(address) -> None:
    assert unreachable(address) is None


@pytest.mark.parametrize("address", ["127.0.0.1:0", "127.0.0.1:65536", "host:port", ":6379",
                                     "127.0.0.1:+80", "127.0.0.1:",
                                     # digits that are not ASCII: int() reads the first as 6379,
                                     # the second (a superscript) raises
                                     "127.0.0.1:\uff16\uff13\uff17\uff19", "127.0.0.1:80\u00b2"])
def test_a_malformed_port_is_named(address) -> None:
    assert unreachable(address) == (
        f"not HOST:PORT with a port in [1, 65535]: {address!r}"
    )


def test_the_highest_port_is_a_port() -> None:
    """65535 is in [1, 65535]: the address is tried (nothing answers, or something does), not
    refused as malformed."""
    reason = unreachable("127.0.0.1:65535", timeout=2.0)
    assert reason is None or reason.startswith("nothing answers at 127.0.0.1:65535 within 2 s")


def test_an_ipv6_address_in_brackets_is_reached() -> None:
    """``[::1]:PORT``: the brackets are the URL form of an IPv6 host, not part of its name."""
    try:
        server = socket.create_server(("::1", 0), family=socket.AF_INET6)
    except OSError:
        pytest.skip("no IPv6 loopback here")
    with server:
        port = server.getsockname()[1]
        assert unreachable(f"[::1]:{port}") is None
        assert unreachable(f"ray://[::1]:{port}") is None
    reason = unreachable(f"[::1]:{port}", timeout=2.0)
    assert reason is not None and reason.startswith(f"nothing answers at ::1:{port} within 2 s")
