"""A tensor file is compared with what its reader expects from its header — names, dtypes,
shapes — before any of its tensors is read: a file that declares an extra tensor of a gigabyte
(a hole on disk) is refused without the gigabyte being allocated."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from declared import declare_tensor, peak_growth
from helpers import NETWORK_SPECS, shipped_agent

from agents.network import build_policy, expected_tensors, parameter_count
from agents.schema import check_spec

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


def test_a_large_network_padded_by_a_sparse_tensor_is_refused_before_it_is_built(
    tmp_path: Path,
) -> None:
    """agent.json describing 0.9 GiB of parameters (within agents.schema's bounds) beside the
    shipped agent's few real tensors and a hole that makes the file as large: the names of the
    file's header are compared with the described network's before the network is built (it
    was built, 1.1 GiB, and only then compared)."""
    agent = Path(shutil.copytree(shipped_agent(), tmp_path / "agent"))
    meta = json.loads((agent / "agent.json").read_text())
    meta["policy"]["net_arch"] = {"pi": [4096] * 8, "vf": [4096] * 8}
    (agent / "agent.json").write_text(json.dumps(meta))
    count = parameter_count(check_spec("agent.json", meta["policy"]))
    declare_tensor(agent / "policy.safetensors", "junk", 4 * count)
    growth, message = peak_growth(
        f"from agents.policy import load_agent; load_agent({str(shipped_agent())!r})",
        f"load_agent({str(agent)!r})",
    )
    assert "policy.safetensors: the tensors do not fit the network of agent.json" in message
    assert "'mlp_extractor.policy_net.14.weight'" in message and "unexpected ['junk']" in message
    assert growth < ALLOWED, f"{growth / 2**20:.0f} MiB"


@pytest.mark.parametrize("spec", NETWORK_SPECS)
def test_the_tensors_computed_from_a_description_are_the_built_network_s(spec: dict) -> None:
    """What the weights file's header is compared with before the network is built is the
    state dict the network has once built: every name, dtype and shape."""
    spec = check_spec("test", {"activation_fn": "tanh", **spec})
    built = build_policy(spec, "test").state_dict()
    expected = expected_tensors(spec)
    assert sorted(expected) == sorted(built)
    for name, tensor in built.items():
        assert (expected[name].dtype, expected[name].shape) == (tensor.dtype, tensor.shape), name


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


def test_weights_of_another_dtype_are_refused_naming_the_tensor(tmp_path: Path) -> None:
    """The shipped agent's tensors rewritten as float64 (the same names and shapes, twice the
    bytes) are refused, the first float tensor named with the dtype the network needs: torch
    would cast them on loading, the file is not the network agent.json describes."""
    from safetensors.torch import load_file, save_file

    from agents.policy import load_agent
    from imm_gym.validation import ConfigError

    agent = Path(shutil.copytree(shipped_agent(), tmp_path / "agent"))
    file = agent / "policy.safetensors"
    tensors = load_file(str(file))
    save_file({k: v.double() if v.is_floating_point() else v for k, v in tensors.items()},
              str(file))
    with pytest.raises(ConfigError, match=r"is torch\.float64 \(.*\), the network of agent\.json "
                                          r"needs torch\.float32"):
        load_agent(agent)


@pytest.mark.parametrize("width", [256, 160])
def test_a_file_of_one_to_four_bytes_a_parameter_is_refused_as_too_small(
    tmp_path: Path, width: int
) -> None:
    """A description of c parameters beside the shipped weights file of s bytes with
    c <= s < 4 c (float32 parameters take 4 bytes each) is refused by its size, before the
    names are compared: layers of 256 make it about 1.3 bytes a parameter, of 160 about 2.9
    (a file of half the bytes the floats need is refused as well as one of a quarter)."""
    agent = Path(shutil.copytree(shipped_agent(), tmp_path / "agent"))
    meta = json.loads((agent / "agent.json").read_text())
    meta["policy"]["net_arch"] = {"pi": [width, width], "vf": [width, width]}
    (agent / "agent.json").write_text(json.dumps(meta))
    count = parameter_count(check_spec("agent.json", meta["policy"]))
    size = (agent / "policy.safetensors").stat().st_size
    assert count <= size < 4 * count
    from agents.policy import load_agent
    from imm_gym.validation import ConfigError

    with pytest.raises(ConfigError, match=f"{size} bytes, fewer than the {4 * count} of the "
                                          f"{count} float32 parameters"):
        load_agent(agent)
