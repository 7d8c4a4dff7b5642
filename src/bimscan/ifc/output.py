"""Where bimscan writes an IFC file (make-building's building, furnish's and progress's copies): the
one check every IFC output goes through before any work."""

from __future__ import annotations

import os
from pathlib import Path

from bimscan.errors import OutputError
from bimscan.io._writer import check_output_path


def check_ifc_output(out: str | Path, *, overwrite: bool, source: str | Path | None = None,
                     like: str = "model.ifc", role: str = "the model") -> Path:
    """``out`` as a Path, or an OutputError now: not ``.ifc`` (``like``: a name to suggest), the model
    ``source`` the copy is made from (``role``: what it is, in the message), or whatever
    ``check_output_path`` refuses (a missing or read-only folder, something there without
    ``overwrite``, with it anything bimscan may not replace: an IFC is replaced only when bimscan
    wrote it, ``bimscan.files.ifc_authors``)."""
    out = Path(out)
    if out.suffix.lower() != ".ifc":
        raise OutputError(f"output file must end in .ifc, got {str(out)!r}; name it like {like}")
    if source is not None and out.exists() and Path(source).exists() and os.path.samefile(out, source):
        raise OutputError(f"{out} is {role}; write the copy to another file")
    check_output_path(out, overwrite=overwrite)
    return out
