"""The on-disk cache of generated kernel modules: where it lives, how entries are written and checked.

A generated module is a Python file ``vnhc_gen_<key>.py`` in `cache_dir`; numba keeps its
machine code beside it (``__pycache__``), so a later process neither generates nor compiles again.
The key is a hash of everything the file is made from (see
`vnhc_gym.mechanics.codegen.module_key`), so an edit of any of those sources gives a new file
instead of a stale one.

Entries are written atomically (a temporary file, then a rename) with a checksum of their text on
the first line, and checked when they are loaded: a truncated, emptied or otherwise damaged file is
rebuilt, with one warning.  An unusable cache folder (read-only, or a file) falls back to a
per-user folder in the temporary directory, with one warning that names ``VNHC_GYM_CACHE_DIR``.

The package ships the generated modules of its own systems and environments (`SHIPPED_DIR`): a
cache miss whose key is there copies that file instead of generating it, so a first run skips the
symbolic work (minutes for the spacecraft) and only compiles.  A shipped file has the same key as a
generated one, so it is used only while every source it was made from is unchanged;
``python -m vnhc_gym.mechanics.ship`` rewrites the folder after an edit.
"""

from __future__ import annotations

import hashlib
import importlib.util
import io
import os
import pickle
import pickletools
import sys
import tempfile
import threading
import warnings
from collections.abc import Callable, Iterable
from pathlib import Path
from types import ModuleType

__all__ = ["CacheWarning", "SHIPPED_DIR", "cache_dir", "load_module", "shipped_source"]

#: Bumped when the layout of the cache folder changes (every entry is then rebuilt).
LAYOUT_VERSION = "2"
_HEADER = "# vnhc_gym generated module; sha256 of the rest: "
_LOCK = threading.RLock()
_LOADED: dict[str, ModuleType] = {}
_RESOLVED: dict[str, Path] = {}
#: The generated modules shipped with the package (module docstring).
SHIPPED_DIR = Path(__file__).with_name("shipped")


class CacheWarning(UserWarning):
    """The kernel cache could not be used as it was (a fallback folder, or a rebuilt entry)."""


def _configured_root() -> Path:
    root = os.environ.get("VNHC_GYM_CACHE_DIR")
    if root:
        return Path(root).expanduser()
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "vnhc_gym"


def _usable(folder: Path) -> str | None:
    """Why ``folder`` cannot hold the cache (None if it can): created if missing, then written to."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        return "it exists and is not a folder"
    except OSError as exc:
        return f"it cannot be created ({exc.strerror or exc})"
    if not folder.is_dir():
        return "it is not a folder"
    try:
        fd, probe = tempfile.mkstemp(dir=folder, prefix=".probe-")
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        return f"it is not writable ({exc.strerror or exc})"
    return None


def cache_dir() -> Path:
    """The folder of generated modules: ``$VNHC_GYM_CACHE_DIR``, else ``~/.cache/vnhc_gym``.

    If that folder cannot be created or written, a per-user folder in the temporary directory is
    used instead, with one `CacheWarning` per process that says why and names
    ``VNHC_GYM_CACHE_DIR``.
    """
    configured = _configured_root()
    with _LOCK:
        if str(configured) in _RESOLVED:
            return _RESOLVED[str(configured)]
        folder = configured / f"layout-{LAYOUT_VERSION}"
        why = _usable(folder)
        if why is not None:
            user = getattr(os, "getuid", lambda: "user")()
            fallback = Path(tempfile.gettempdir()) / f"vnhc_gym-{user}" / f"layout-{LAYOUT_VERSION}"
            warnings.warn(f"vnhc_gym: the kernel cache folder {folder} is unusable: {why}; using {fallback} "
                          "instead. Set VNHC_GYM_CACHE_DIR to a writable folder to keep compiled kernels there.",
                          CacheWarning, stacklevel=3)
            fallback_why = _usable(fallback)
            if fallback_why is not None:
                raise OSError(f"no usable folder for vnhc_gym's kernel cache: {folder} ({why}) and {fallback} "
                              f"({fallback_why}); set VNHC_GYM_CACHE_DIR to a writable folder")
            folder = fallback
        _RESOLVED[str(configured)] = folder
        return folder


def _digest(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()


def _write(path: Path, source: str) -> None:
    """Publish ``source`` at ``path`` atomically: concurrent processes may race to write it."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}-", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(_HEADER + _digest(source) + "\n" + source)
        os.chmod(tmp, 0o644)  # mkstemp makes it private; a shared cache folder needs it readable
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _check_text(path: Path) -> str | None:
    """Why the file at ``path`` is damaged (None if its checksum matches its text)."""
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        return f"unreadable ({exc})"
    head, _, body = text.partition("\n")
    if not head.startswith(_HEADER):
        return "no checksum line (empty or truncated)"
    if head[len(_HEADER):] != _digest(body):
        return "its text does not match its checksum (truncated or edited)"
    return None


def shipped_source(key: str) -> str | None:
    """The text of the shipped module ``key`` without its checksum line (None if the package does
    not ship it, or its copy fails its checksum)."""
    shipped = SHIPPED_DIR / f"vnhc_gen_{key}.py"
    if not shipped.is_file() or _check_text(shipped) is not None:
        return None
    return shipped.read_text(encoding="utf-8").partition("\n")[2]


def _machine_code_dir(path: Path) -> Path:
    """Where numba keeps the machine code of the module at ``path``: beside it, or under
    ``NUMBA_CACHE_DIR`` when that is set (numba's own rule for the sub-folder)."""
    from numba.core import config
    from numba.core.caching import _CacheLocator

    cache_root = getattr(config, "CACHE_DIR", "")
    if cache_root:
        return Path(cache_root) / _CacheLocator.get_suitable_cache_subpath(str(path))
    return path.parent / "__pycache__"


def _machine_code_files(path: Path) -> list[Path]:
    return sorted(_machine_code_dir(path).glob(f"{path.stem}.*"))


def _complete_pickles(data: bytes, count: int) -> bool:
    """Whether ``data`` holds ``count`` complete, well-formed pickles (read opcode by opcode, never
    executed, so this is cheap and safe)."""
    stream = io.BytesIO(data)
    try:
        for _ in range(count):
            for _opcode, _arg, _pos in pickletools.genops(stream):
                pass
    except Exception:  # noqa: BLE001 - any parse failure means a damaged file
        return False
    return stream.tell() == len(data)


def _check_machine_code(path: Path) -> str | None:
    """Why numba's cached files of ``path`` (index and data) cannot be read (None if they can, or
    there are none)."""
    for file in _machine_code_files(path):
        if file.suffix not in (".nbi", ".nbc"):
            continue
        try:
            data = file.read_bytes()
        except OSError as exc:
            return f"numba file {file.name} is unreadable ({exc})"
        # An index is numba's version tag then the index; a data file one pickle.
        if not _complete_pickles(data, 2 if file.suffix == ".nbi" else 1):
            return f"numba file {file.name} is damaged"
    if any(p.suffix == ".nbi" for p in _machine_code_files(path)):
        index = next(p for p in _machine_code_files(path) if p.suffix == ".nbi")
        try:
            with open(index, "rb") as fh:
                pickle.load(fh)  # numba's version tag
                pickle.loads(fh.read())
        except Exception as exc:  # noqa: BLE001 - any failure means the entry is damaged
            return f"numba index {index.name} is unreadable ({type(exc).__name__})"
    return None


def _discard(path: Path, keep_source: bool = False) -> None:
    for p in [*([] if keep_source else [path]), *_machine_code_files(path)]:
        try:
            p.unlink()
        except FileNotFoundError:
            pass


def _import(path: Path, name: str) -> ModuleType:
    spec = importlib.util.spec_from_file_location(name, path)
    if spec is None or spec.loader is None:  # pragma: no cover - importlib contract
        raise ImportError(f"cannot import generated module {path}")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # numba's cache and pickling look modules up by name
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[name]
        raise
    return module


def load_module(key: str, make_source: Callable[[], str], *, label: str,
                required: Iterable[str] = ()) -> ModuleType:
    """Import the generated module ``key``, generating it first if the cache does not hold it.

    Parameters
    ----------
    key : str
        Hex digest naming the module (see `vnhc_gym.mechanics.codegen.module_key`).
    make_source : callable
        Returns the module's text; called only on a cache miss that the package does not ship (a
        warm start skips all symbolic work).
    label : str
        What the module is for, in the one-line notice printed on stderr the first time its
        kernels are compiled.
    required : iterable of str
        Names the module must define; an entry missing any of them is rebuilt.
    """
    with _LOCK:
        if key in _LOADED:
            return _LOADED[key]
        folder = cache_dir()
        path = folder / f"vnhc_gen_{key}.py"
        name = f"vnhc_gym._generated_{key}"
        required = tuple(required)
        damage = None
        if path.exists():
            damage = _check_text(path)
            if damage is None:
                try:
                    module = _import(path, name)
                except Exception as exc:  # noqa: BLE001 - a damaged entry is rebuilt, not fatal
                    damage = f"it does not import ({type(exc).__name__}: {exc})"
                else:
                    missing = [n for n in required if not hasattr(module, n)]
                    damage = f"it lacks {missing}" if missing else None
            if damage is None:
                # numba's index pickles types of the module, so it can only be read once the module is
                # imported; numba reads it at the first call, so removing it here is still safe.
                code_damage = _check_machine_code(path)
                if code_damage is not None:
                    warnings.warn(f"vnhc_gym: recompiling the damaged machine code of {path.name} ({code_damage})",
                                  CacheWarning, stacklevel=3)
                    _discard(path, keep_source=True)
                if not any(p.suffix == ".nbi" for p in _machine_code_files(path)):
                    _notice(label, folder)
                _LOADED[key] = module
                return module
            warnings.warn(f"vnhc_gym: rebuilding the damaged kernel cache entry {path.name} ({damage})",
                          CacheWarning, stacklevel=3)
            sys.modules.pop(name, None)
            _discard(path)
        source = shipped_source(key)
        if source is None:
            source = make_source()  # validates the definition: an error is raised before any notice of work
        _notice(label, folder)
        _write(path, source)
        module = _import(path, name)
        missing = [n for n in required if not hasattr(module, n)]
        if missing:  # pragma: no cover - a code generation bug, not a cache fault
            raise ImportError(f"generated module {path} lacks {missing}")
        _LOADED[key] = module
        return module


_NOTICED: set[str] = set()


def _notice(label: str, folder: Path) -> None:
    """One line on stderr before kernels compile for the first time (once per label and process)."""
    if label in _NOTICED:
        return
    _NOTICED.add(label)
    print(f"vnhc_gym: compiling kernels for {label} (first use only; cached in {folder})", file=sys.stderr,
          flush=True)
