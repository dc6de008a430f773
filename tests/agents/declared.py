"""Helpers of the tests of tensor files that declare more than they should: a safetensors file
grown by a tensor its header declares (a hole on disk), and the peak memory a fresh interpreter
grows by while it loads one."""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def declare_tensor(file: Path, name: str, nbytes: int) -> None:
    """Add to the safetensors ``file`` a float32 tensor ``name`` of ``nbytes`` bytes after the
    others, written as a hole (a sparse file: the apparent size grows, not the disk's use)."""
    raw = file.read_bytes()
    (size,) = struct.unpack("<Q", raw[:8])
    header = json.loads(raw[8 : 8 + size])
    end = max(v["data_offsets"][1] for k, v in header.items() if k != "__metadata__")
    header[name] = {"dtype": "F32", "shape": [nbytes // 4], "data_offsets": [end, end + nbytes]}
    text = json.dumps(header).encode()
    text += b" " * (-len(text) % 8)
    with file.open("wb") as out:
        out.write(struct.pack("<Q", len(text)) + text + raw[8 + size : 8 + size + end])
        out.truncate(8 + len(text) + end + nbytes)


def peak_growth(warm: str, call: str) -> tuple[int, str]:
    """Run the Python statements ``warm`` (imports, a first load) and then ``call`` in a fresh
    interpreter: the growth of its peak resident memory over ``call`` in bytes and the message
    of the ConfigError ``call`` raised ('' if none)."""
    script = "\n".join([
        "import json, resource, sys",
        "from imm_gym.validation import ConfigError",
        warm,
        "before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss",
        "message = ''",
        "try:",
        f"    {call}",
        "except ConfigError as err:",
        "    message = str(err)",
        "after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss",
        "unit = 1 if sys.platform == 'darwin' else 1024",  # bytes there, KiB on Linux
        "print(json.dumps([(after - before) * unit, message]))",
    ])
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    done = subprocess.run([sys.executable, "-c", script], cwd=ROOT, env=env,
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    growth, message = json.loads(done.stdout.strip().splitlines()[-1])
    return growth, message
