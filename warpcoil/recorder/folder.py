"""One output folder holds exactly one run's outputs.

A command *claims* its folder before it writes anything: it takes a lock file
(``.warpcoil.lock``, created exclusively, holding the process id), so two
runs into one folder cannot interleave; a lock left by a process that no
longer exists (a killed run) is taken over, and so are the temporary files
and folders such a run left (removed: none of them is a finished output). A
folder that already holds a run's outputs (any file name warpcoil writes) is
refused, unless ``overwrite``: then exactly those files are deleted first, so
no old ``result.json``, picture or animation ever sits beside new data.
Files that warpcoil does not write are left alone. A run writes its outputs
into a hidden folder inside (:func:`staged_outputs`) and moves them out when
it ends, so a run killed on the way leaves none of them.
"""

from __future__ import annotations

import os
import re
import secrets
import shutil
import socket
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

LOCK_NAME = ".warpcoil.lock"
TEMPORARY = re.compile(r"^\..+\.tmp-[0-9a-f]{8}")  # atomic_path's and staged_outputs' temporary names


class OutputFolderError(ValueError):
    """An output folder that cannot be used; the message names it and the fix."""


def _missing_folders(path: Path) -> list[Path]:
    """``path`` and its parents that do not exist yet, innermost first, up to the first that does."""
    missing = []
    for folder in (path, *path.parents):
        if folder.exists():
            break
        missing.append(folder)
    return missing


def check_output_path(path: Path, option: str = "-o") -> None:
    """Refuse, before any work, an output path that is a file or cannot be created or written."""
    path = Path(path)
    try:
        exists = path.exists()
    except OSError as error:  # (a name too long)
        raise OutputFolderError(f"{option} {path}: cannot be used ({error.strerror}); fix: choose another "
                                "output folder") from None
    if exists and not path.is_dir():
        raise OutputFolderError(f"{option} {path}: is an existing file, not a folder; fix: give a folder path "
                                f"(it is created if missing), e.g. {option} {path.with_suffix('')}_out")
    missing = _missing_folders(path)
    chain = [path, *path.parents]
    existing = chain[len(missing)] if len(missing) < len(chain) else None
    if existing is not None and not existing.is_dir():
        raise OutputFolderError(f"{option} {path}: {existing} is a file, so the folder cannot be created; fix: "
                                "choose another output folder")
    if existing is not None and not os.access(existing, os.W_OK | os.X_OK):
        raise OutputFolderError(f"{option} {path}: {existing} is not writable; fix: choose a folder you can "
                                "write to, or change its permissions")
    if existing is None or not missing:
        return
    try:
        longest = os.pathconf(existing, "PC_NAME_MAX")
    except (OSError, ValueError):
        longest = 255
    for folder in reversed(missing):  # (outermost first: the first of them too long is named)
        if len(os.fsencode(folder.name)) > longest:
            raise OutputFolderError(f"{option} {path}: the name {folder.name[:20]}… is longer than the file system "
                                    f"allows ({longest} bytes); fix: choose a shorter output folder name")
    if hasattr(os, "geteuid") and os.geteuid() == 0:  # (root passes os.access anywhere: try the first to create)
        _probe_folder(missing[-1], path, option)


def _probe_folder(folder: Path, path: Path, option: str) -> None:
    """Create ``folder`` (missing, the first of ``path``'s) and remove it again; refuse where it cannot
    be made (a pseudo file system such as /proc or /sys, a read-only mount). One made meanwhile by
    another run passes, and is left to it."""
    try:
        folder.mkdir()
    except FileExistsError:
        return
    except OSError as error:
        raise OutputFolderError(f"{option} {path}: {folder} cannot be created ({error.strerror}); fix: choose "
                                "another output folder") from None
    try:
        folder.rmdir()
    except OSError:
        pass  # (another run's folder is in it by now)


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _take_lock(folder: Path, option: str) -> Path:
    lock = folder / LOCK_NAME
    me = f"{os.getpid()} {socket.gethostname()}\n"
    for _ in range(2):
        try:
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            try:
                pid_text, _, host = lock.read_text().partition(" ")
                pid, host = int(pid_text), host.strip()
            except (OSError, ValueError):
                pid, host = -1, ""
            if host == socket.gethostname() and pid > 0 and not _pid_alive(pid):
                lock.unlink(missing_ok=True)  # left by a run that was killed: take it over
                continue
            owner = f"process {pid} on {host}" if pid > 0 else "another process"
            raise OutputFolderError(
                f"{option} {folder}: another warpcoil run ({owner}) is writing into this folder; fix: wait for it "
                f"to finish or choose another output folder (if no run is going on, delete {lock})") from None
        with os.fdopen(fd, "w") as file:
            file.write(me)
        return lock
    raise OutputFolderError(f"{option} {folder}: cannot take the lock {lock}; fix: delete it and run again")


def previous_outputs(folder: Path, names: Iterable[str], folder_pattern: str | None = None) -> list[Path]:
    """The files (and, matching ``folder_pattern``, sub-folders) of an earlier run in ``folder``."""
    names = set(names)
    found = []
    for entry in sorted(folder.iterdir()):
        if entry.name in names:
            found.append(entry)
        elif folder_pattern and entry.is_dir() and re.fullmatch(folder_pattern, entry.name):
            found.append(entry)
    return found


def clear_outputs(path: Path, names: Iterable[str], folder_pattern: str | None = None) -> None:
    """Delete an earlier run's outputs in ``path`` (``names``; in sub-folders matching ``folder_pattern``
    those names, and the sub-folder where nothing else is left)."""
    names = tuple(names)
    for entry in previous_outputs(path, names, folder_pattern):
        if entry.is_dir():
            for inner in previous_outputs(entry, names):
                inner.unlink()
            if not any(entry.iterdir()):
                entry.rmdir()
        else:
            entry.unlink()


@contextmanager
def claimed_folder(path: Path, names: Iterable[str], overwrite: bool, option: str = "-o",
                   folder_pattern: str | None = None, clear: bool = True) -> Iterator[Path]:
    """Create (if needed) and lock ``path`` for one run; refuse or (``overwrite``)
    delete an earlier run's outputs (``names``; sub-folders matching
    ``folder_pattern``) — or, ``clear`` False, leave that to the caller once its input is
    checked (:func:`clear_outputs`: a bad input then keeps them). On exit the lock is
    released, and a folder this call created that is still empty is removed again."""
    path = Path(path)
    check_output_path(path, option)
    made = _missing_folders(path)  # (innermost first)
    created = bool(made)  # (path is then the first of them)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        for folder in made:  # the parents this call made, and no others
            try:
                folder.rmdir()
            except OSError:
                pass
        raise OutputFolderError(f"{option} {path}: cannot be created ({error.strerror}); fix: choose another "
                                "output folder") from None
    try:
        lock = _take_lock(path, option)
    except OutputFolderError:
        if created:
            shutil.rmtree(path, ignore_errors=True)
        raise
    try:
        for leftover in (p for p in path.iterdir() if TEMPORARY.match(p.name)):  # a killed run's (the lock is ours)
            shutil.rmtree(leftover) if leftover.is_dir() else leftover.unlink()
        names = tuple(names)
        old = previous_outputs(path, names, folder_pattern)
        if old and not overwrite:
            shown = ", ".join(p.name for p in old[:4]) + (", …" if len(old) > 4 else "")
            raise OutputFolderError(f"{option} {path}: already holds the outputs of an earlier run ({shown}); fix: "
                                    "add --overwrite to replace them, or choose another output folder")
        if clear:
            clear_outputs(path, names, folder_pattern)
        yield path
    finally:
        lock.unlink(missing_ok=True)
        if created and path.is_dir() and not any(path.iterdir()):
            path.rmdir()


def resumed_folder(path: Path, option: str = "-o"):
    """:func:`claimed_folder` for a resumed sweep or plan: its member folders and summary stay (the sweep
    checks them); a folder holding a single run's outputs (a result.json of its own) is refused."""
    from .outputs import RESULT_JSON

    if (Path(path) / RESULT_JSON).is_file():
        raise OutputFolderError(f"{option} {path}: holds a single run's outputs ({RESULT_JSON}, …), not a sweep's "
                                "or plan's member folders, so --resume has nothing of it to keep; fix: choose "
                                "another output folder")
    return claimed_folder(path, (), overwrite=True, option=option)


@contextmanager
def staged_outputs(folder: Path, last: str) -> Iterator[Path]:
    """A hidden folder inside ``folder`` (a temporary name, :data:`TEMPORARY`) for a run to
    write its outputs into. When the block ends, each of them is moved into ``folder``
    (``last`` last: its presence means the others are there); when it raises, the hidden
    folder is removed. A run killed before then leaves only that folder, which the next
    claim of ``folder`` removes."""
    stage = Path(folder) / f".run.tmp-{secrets.token_hex(4)}"
    stage.mkdir()
    try:
        yield stage
        for name in sorted((p.name for p in stage.iterdir()), key=lambda name: name == last):
            os.replace(stage / name, Path(folder) / name)
        stage.rmdir()
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        raise

