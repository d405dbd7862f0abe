"""Files written whole or not at all, by writers that take a file name (matplotlib, rerun,
asammdf, python-can): a temporary name beside the file, renamed into place when the writer is
done, removed whatever else ends it (an error, a full disk, a signal), so a run folder never
holds a 0-byte ``figure.png`` or a ``recording.rrd`` cut short. (``rig.outputs.write_text``
does the same for text the rig has in hand.)"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from pathlib import Path


@contextlib.contextmanager
def whole(path: Path) -> Iterator[Path]:
    """The temporary name to write ``path`` to (its suffix in lower case: writers choose
    their format, or change the name, by it)."""
    tmp = path.with_name(f".{path.stem}.tmp-{os.getpid()}{path.suffix.lower()}")
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        with contextlib.suppress(OSError):  # (a read-only file system refuses even this)
            tmp.unlink(missing_ok=True)
