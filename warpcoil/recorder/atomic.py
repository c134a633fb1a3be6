"""Atomic file output: a failed run never leaves a half-written file behind."""

from __future__ import annotations

import os
import secrets
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


@contextmanager
def atomic_path(final_path: Path) -> Iterator[Path]:
    """Yield a temporary path next to ``final_path``; move it there on success.

    The temporary file lives in the same directory (so the final ``os.replace``
    is an atomic rename on the same filesystem) and keeps the same suffix, e.g.
    ``run.usdc`` -> ``.run.usdc.tmp-ab12cd.usdc``, so writers that pick their
    format from the extension still work. On an exception the temporary file
    is deleted and the exception re-raised; ``final_path`` is left untouched.
    The temporary file is not pre-created (the writer creates it, so it gets
    the usual umask permissions rather than ``mkstemp``'s 0600).
    """
    final_path = Path(final_path)
    tmp_path = final_path.with_name(
        f".{final_path.name}.tmp-{secrets.token_hex(4)}{final_path.suffix}"
    )
    try:
        yield tmp_path
        os.replace(tmp_path, final_path)
    except BaseException:
        tmp_path.unlink(missing_ok=True)
        raise


def write_text_atomic(path: Path, text: str, encoding: str = "utf-8") -> None:
    """Write ``text`` to ``path`` atomically (all or nothing)."""
    with atomic_path(Path(path)) as tmp_path:
        tmp_path.write_text(text, encoding=encoding)


@contextmanager
def all_or_none(*paths: Path) -> Iterator[None]:
    """Files written together in the block: when it raises (a full disk), each of ``paths`` is removed,
    so none is left without the others."""
    try:
        yield
    except BaseException:
        for path in paths:
            Path(path).unlink(missing_ok=True)
        raise


def write_folder_atomic(folder: Path, files: dict[str, bytes]) -> None:
    """Write ``files`` (name → bytes) as the whole content of ``folder``: built
    under a temporary name beside it, then renamed into place, so the folder
    holds either all of them or is absent (an older folder is removed first)."""
    folder = Path(folder)
    tmp_folder = folder.with_name(f".{folder.name}.tmp-{secrets.token_hex(4)}")
    try:
        tmp_folder.mkdir(parents=True)
        for name, data in files.items():
            (tmp_folder / name).write_bytes(data)
        if folder.exists():
            shutil.rmtree(folder)
        os.replace(tmp_folder, folder)
    except BaseException:
        shutil.rmtree(tmp_folder, ignore_errors=True)
        raise
