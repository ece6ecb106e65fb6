"""A disk that fills up: files opened for writing below a folder fail with ENOSPC while it is
full, as on a real file system (data a failed write left behind is tried again, and fails
again, when the file is closed)."""

from __future__ import annotations

import errno
import os
from pathlib import Path


class FullDisk:
    def __init__(self, root: Path, monkeypatch):
        self.root = Path(root)
        self.full = False
        real_open = Path.open

        def open_(path: Path, mode: str = "r", *args, **kwargs):
            file = real_open(path, mode, *args, **kwargs)
            return _File(file, self) if "w" in mode and path.is_relative_to(self.root) else file

        monkeypatch.setattr(Path, "open", open_)


class _File:
    def __init__(self, file, disk: FullDisk):
        self._file, self._disk, self._unwritten = file, disk, False

    def _refuse_when_full(self) -> None:
        if self._disk.full:
            self._unwritten = True
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    def write(self, data) -> int:
        self._refuse_when_full()
        return self._file.write(data)

    def flush(self) -> None:
        self._refuse_when_full()
        self._file.flush()

    def close(self) -> None:
        self._file.close()
        if self._unwritten and self._disk.full:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
