"""numba's on-disk caches of the package kept in step with the source they were compiled from.

numba reuses a compiled function's cache while the file that defines it is unchanged (its index
records that file's modification time and size), even when code compiled *into* it has changed
elsewhere: functions it inlines or calls from other files, and the module-level constants it
reads, frozen at compile time. A kernel edited in ``imm_gym/tracking/kernels/imm.py`` would keep
running inside the cached ``imm_gym/sim/kernels.py`` and ``imm_gym/sim/solo.py`` — after a
``git pull`` too, where the old code would then run without an error.

:func:`refresh` (run when this module is imported: ``imm_gym`` imports it first) hashes the
source of every module of the package that imports numba and of the package modules those import
(at the top of the file), and compares the digest with the one recorded beside the caches when
they were last refreshed. If the two differ, every numba cache file of the package (``*.nbi``,
``*.nbc`` under its ``__pycache__`` directories) is deleted: numba compiles again at the first call
(``python -m imm_gym.precompile`` does it in parallel). Where the package directory is
read-only numba keeps its caches elsewhere (``NUMBA_CACHE_DIR``) and nothing is done here.
"""

from __future__ import annotations

import hashlib
import re
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent
#: the recorded digest, beside the package's own bytecode
DIGEST_FILE = Path("__pycache__") / "numba_sources.sha256"
CACHE_SUFFIXES = (".nbi", ".nbc")


#: a line importing numba; a line importing from a package module (its name)
_NUMBA = re.compile(rb"^(?:import numba|from numba[. ])", re.MULTILINE)
_PACKAGE_IMPORT = re.compile(rb"^(?:from|import) (imm_gym(?:\.\w+)+)", re.MULTILINE)


def _module_file(name: str, root: Path) -> Path | None:
    """The source file of the package module ``name`` (``imm_gym.a.b``), if it exists."""
    path = root.joinpath(*name.split(".")[1:])
    for candidate in (path.with_suffix(".py"), path / "__init__.py"):
        if candidate.is_file():
            return candidate
    return None


def compiled_sources(root: Path = PACKAGE) -> list[Path]:
    """The modules under ``root`` that import numba and the package modules they import."""
    sources: set[Path] = set()
    for path in root.rglob("*.py"):
        source = path.read_bytes()
        if _NUMBA.search(source):
            sources.add(path)
            for name in _PACKAGE_IMPORT.findall(source):
                if (f := _module_file(name.decode(), root)) is not None:
                    sources.add(f)
    return sorted(sources)


def source_digest(root: Path = PACKAGE) -> str:
    """SHA-256 over the relative paths and bytes of :func:`compiled_sources`."""
    digest = hashlib.sha256()
    for path in compiled_sources(root):
        digest.update(path.relative_to(root).as_posix().encode() + b"\0")
        digest.update(path.read_bytes() + b"\0")
    return digest.hexdigest()


def refresh(root: Path = PACKAGE) -> bool:
    """Delete the package's numba caches if the compiled sources changed since they were last
    refreshed (or were never recorded), and record the current digest; True if it was new."""
    stamp = root / DIGEST_FILE
    try:
        current = source_digest(root)
        if stamp.is_file() and stamp.read_text() == current:
            return False
        for path in root.rglob("*"):
            if path.suffix in CACHE_SUFFIXES and path.parent.name == "__pycache__":
                path.unlink(missing_ok=True)
        stamp.parent.mkdir(exist_ok=True)
        stamp.write_text(current)
    except OSError:  # a read-only installation: numba caches elsewhere
        return False
    return True


refresh()
