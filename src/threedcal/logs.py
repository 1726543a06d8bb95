"""Stage logs that keep the terminal's progress bars: stderr goes to the log file and the terminal."""

from __future__ import annotations

import contextlib
import logging
import sys
import traceback
from collections.abc import Iterator
from pathlib import Path
from typing import TextIO


class _Tee:
    def __init__(self, *streams: TextIO):
        self.streams = streams

    def write(self, text: str) -> int:
        for stream in self.streams:
            stream.write(text)
        return len(text)

    def flush(self) -> None:
        for stream in self.streams:
            stream.flush()

    def isatty(self) -> bool:
        return False


@contextlib.contextmanager
def stage_log(path: str | Path | None) -> Iterator[logging.Logger]:
    """Copy stderr (tqdm, warnings, tracebacks) and a `threedcal` logger into `path` while the stage runs."""
    logger = logging.getLogger("threedcal")
    if path is None:
        yield logger
        return
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w") as log_file:
        original = sys.stderr
        sys.stderr = _Tee(original, log_file)
        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(message)s"))
        logger.addHandler(handler)
        logger.setLevel(logging.INFO)
        try:
            yield logger
        except BaseException:
            traceback.print_exc()
            raise
        finally:
            logger.removeHandler(handler)
            sys.stderr = original
