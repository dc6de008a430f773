"""A tensor file is compared with what its reader expects from its header — names, dtypes,
shapes — before any of its tensors is read: a file that declares an extra tensor of a gigabyte
(a hole on disk) is refused without the gigabyte being allocated."""

from __future__ import annotations

import shutil
from pathlib import Path

from declared import declare_tensor, peak_growth
from helpers import shipped_agent

#: A tensor the files declare beyond the expected ones, and the growth of the peak memory
#: allowed while they are refused (far below it).
EXTRA, ALLOWED = 2**30, 100 * 2**20


def test_a_weights_file_declaring_an_extra_tensor_is_refused_before_it_is_read(
    tmp_path: Path,
) -> None:
    agent = Path(shutil.copytree(shipped_agent(), tmp_path / "agent"))
    declare_tensor(agent / "policy.safetensors", "junk", EXTRA)
    growth, message = peak_growth(
        f"from agents.policy import load_agent; load_agent({str(shipped_agent())!r})",
        f"load_agent({str(agent)!r})",
    )
    assert "policy.safetensors: the tensors do not fit the network" in message
    assert "unexpected ['junk']" in message
    assert growth < ALLOWED, f"{growth / 2**20:.0f} MiB"


def test_a_selector_member_declaring_an_extra_tensor_is_refused_before_it_is_read(
    tmp_path: Path,
) -> None:
    from test_selector import write_selector

    directory = write_selector(tmp_path)
    declare_tensor(directory / "net_0.safetensors", "junk", EXTRA)
    intact = write_selector(tmp_path / "intact")
    growth, message = peak_growth(
        f"from agents.selector import load_selector; load_selector({str(intact)!r})",
        f"load_selector({str(directory)!r})",
    )
    assert "member 'net_0.safetensors' does not fit" in message
    assert "tensor 'junk': (268435456,) in the file, absent in the network" in message
    assert growth < ALLOWED, f"{growth / 2**20:.0f} MiB"
