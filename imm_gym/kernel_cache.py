"""numba's on-disk caches of the package kept in step with the source they were compiled from.

numba reuses a compiled function's cache while the file that defines it is unchanged (its index
records that file's modification time and size), even when code compiled *into* it has changed
elsewhere: functions it inlines or calls from other files, and the module-level constants it
reads, frozen at compile time. A kernel edited in ``imm_gym/tracking/kernels/imm.py`` would keep
running inside the cached ``imm_gym/sim/kernels.py`` and ``imm_gym/sim/solo.py`` — after a
``git pull`` too, where the old code would then run without an error.

:func:`refresh` (run when this module is imported: ``imm_gym`` imports it first) hashes the
source of every module of the package that imports numba and of the package modules those import
(``import imm_gym.a``, ``from imm_gym.a import b``, ``from imm_gym import a``, at the top of the
file or indented), and compares the digest with the one recorded beside the caches when
they were last refreshed. If the two differ, every numba cache file of the package (``*.nbi``,
``*.nbc`` under its ``__pycache__`` directories) is deleted: numba compiles again at the first call
(``python -m imm_gym.precompile`` does it in parallel). With ``NUMBA_CACHE_DIR`` set numba keeps
the caches there instead, one folder per source directory named ``<directory>_<SHA-1 of its
absolute path>`` (``numba.core.caching``); those folders are refreshed the same way, against a
digest recorded beside them. Where the package directory is read-only and no ``NUMBA_CACHE_DIR``
is set, numba caches in the user's cache directory and nothing is done here.
"""

from __future__ import annotations

import hashlib
import os
import re
from collections.abc import Iterator
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent
#: the recorded digest, beside the package's own bytecode
DIGEST_FILE = Path("__pycache__") / "numba_sources.sha256"
CACHE_SUFFIXES = (".nbi", ".nbc")


#: a line importing numba; a line of imports (its modules, the package's taken); a line importing
#: from the package or a package module (its name and the names it imports), indented or not
_NUMBA = re.compile(rb"^[ \t]*(?:import numba|from numba[. ])", re.MULTILINE)
_IMPORT = re.compile(rb"^[ \t]*import ([^\n;]*)", re.MULTILINE)
_PACKAGE_FROM = re.compile(
    rb"^[ \t]*from (imm_gym(?:\.\w+)*) import[ \t]*(\([^)]*\)|(?:[^\n#;\\]|\\\n)*)",
    re.MULTILINE,
)
_COMMENT = re.compile(rb"#[^\n]*")


def _module_file(name: str, root: Path) -> Path | None:
    """The source file of the package module ``name`` (``imm_gym.a.b``), if it exists."""
    path = root.joinpath(*name.split(".")[1:])
    for candidate in (path.with_suffix(".py"), path / "__init__.py"):
        if candidate.is_file():
            return candidate
    return None


def _imported_modules(source: bytes) -> Iterator[str]:
    """The names of the package modules ``source`` may import: ``import imm_gym.a``, ``from
    imm_gym.a import b`` (``imm_gym.a`` and ``imm_gym.a.b``, a module or a name with no file of
    its own) and ``from imm_gym import a`` (``imm_gym`` and ``imm_gym.a``), indented or not, the
    names in parentheses or over continued lines too, several modules on one ``import`` line, the
    comments dropped first (a ``)`` in one ended a parenthesised list)."""
    source = _COMMENT.sub(b"", source)
    for listed in _IMPORT.findall(source):
        for entry in listed.decode().split(","):
            if entry.split() and entry.split()[0].startswith("imm_gym."):
                yield entry.split()[0]
    for module, names in _PACKAGE_FROM.findall(source):
        yield module.decode()
        listed = names.replace(b"\\\n", b" ").decode()
        for entry in listed.strip("()").split(","):
            if entry.split():
                yield f"{module.decode()}.{entry.split()[0]}"


def compiled_sources(root: Path = PACKAGE) -> list[Path]:
    """The modules under ``root`` that import numba and the package modules they import."""
    sources: set[Path] = set()
    for path in root.rglob("*.py"):
        source = path.read_bytes()
        if _NUMBA.search(source):
            sources.add(path)
            for name in _imported_modules(source):
                if (f := _module_file(name, root)) is not None:
                    sources.add(f)
    return sorted(sources)


def source_digest(root: Path = PACKAGE) -> str:
    """SHA-256 over the relative paths and bytes of :func:`compiled_sources`."""
    digest = hashlib.sha256()
    for path in compiled_sources(root):
        digest.update(path.relative_to(root).as_posix().encode() + b"\0")
        digest.update(path.read_bytes() + b"\0")
    return digest.hexdigest()


def numba_folder(directory: Path) -> str:
    """The folder under ``NUMBA_CACHE_DIR`` where numba caches the functions of the source files
    in ``directory``: its name and the SHA-1 of its absolute path (``numba.core.caching``'s
    ``UserProvidedCacheLocator``)."""
    path = os.path.abspath(directory)
    return f"{os.path.basename(path)}_{hashlib.sha1(path.encode()).hexdigest()}"


def cache_locations(root: Path, cache_dir: str | None) -> Iterator[tuple[list[Path], Path]]:
    """Each place numba may keep the package's caches, as its folders and the digest file
    recorded for them: the package's ``__pycache__`` directories, and with ``cache_dir``
    (``NUMBA_CACHE_DIR``) numba's folders there."""
    directories = sorted({p.parent for p in root.rglob("*.py")})
    yield [d / "__pycache__" for d in directories], root / DIGEST_FILE
    if cache_dir:
        base = Path(cache_dir)
        yield [base / numba_folder(d) for d in directories], base / (
            numba_folder(root) + ".sha256"
        )


def refresh(root: Path = PACKAGE, cache_dir: str | None = None) -> bool:
    """Delete the package's numba caches if the compiled sources changed since they were last
    refreshed (or were never recorded), and record the current digest, in every place of
    :func:`cache_locations` (``cache_dir`` by default ``NUMBA_CACHE_DIR``); True if the digest
    was new to one of them."""
    if cache_dir is None:
        cache_dir = os.environ.get("NUMBA_CACHE_DIR")
    current = source_digest(root)
    refreshed = False
    for folders, stamp in cache_locations(root, cache_dir):
        try:
            if stamp.is_file() and stamp.read_text() == current:
                continue
            for folder in folders:
                if folder.is_dir():
                    for path in folder.iterdir():
                        if path.suffix in CACHE_SUFFIXES:
                            path.unlink(missing_ok=True)
            stamp.parent.mkdir(parents=True, exist_ok=True)
            stamp.write_text(current)
        except OSError:  # a read-only place: numba does not cache there
            continue
        refreshed = True
    return refreshed


refresh()
