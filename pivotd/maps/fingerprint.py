"""What identifies a loaded map on disk, so that a reload can tell whether the map file changed.

A map is read again on SIGHUP only when its settings changed or one of its files did: same path, size,
modification time (ns) and inode means the same content for every writer that replaces or rewrites a file
(an editor, ``cp``, ``rsync``, a mapping tool). A COLMAP model is a directory: each file in it counts.
"""

from __future__ import annotations

import os
from pathlib import Path

#: One file: (path, size [bytes], mtime [ns], inode), or (path,) when it cannot be read.
FileStamp = tuple
#: The stamps of the map's files, map file first, then the occupancy file.
MapIdentity = tuple[FileStamp, ...]


def file_stamp(path: Path) -> FileStamp:
    """(path, size, mtime_ns, inode) of ``path`` (a directory: its files, by name); (path,) if it is unreadable."""
    try:
        st = path.stat()
        if path.is_dir():
            entries = sorted(os.scandir(path), key=lambda e: e.name)
            return (str(path), tuple(file_stamp(Path(e.path)) for e in entries if not e.is_dir()))
        return (str(path), st.st_size, st.st_mtime_ns, st.st_ino)
    except OSError:
        return (str(path),)


def map_identity(*files: str | Path | None) -> MapIdentity:
    """The identity of the map's ``files`` (e.g. map file, occupancy file; None entries skipped)."""
    return tuple(file_stamp(Path(p)) for p in files if p is not None)
