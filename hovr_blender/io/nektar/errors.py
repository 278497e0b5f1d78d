"""The reader's one error type, and the guard that makes every failure one."""
from __future__ import annotations

import numpy as np

from ...engine import limits
from ...engine.mesh import MeshError


class NektarError(ValueError):
    """A Nektar++ file this reader cannot use; the message names the file and the record."""


def guard(path, read):
    """read(); an exception that is not a NektarError becomes one naming the file (marked
    'unexpected' so tests can tell a reader bug from a diagnosed input error)."""
    try:
        return read()
    except NektarError:
        raise
    except MeshError as exc:
        raise NektarError(f"{path}: {exc}") from exc
    except (limits.ResourceLimitError, limits.UnsafeFileError) as exc:  # their messages name the file
        raise NektarError(str(exc)) from exc
    except (ValueError, IndexError, KeyError, TypeError, OverflowError, ZeroDivisionError,
            ArithmeticError, np.linalg.LinAlgError, RecursionError, UnicodeError) as exc:
        raise NektarError(f"{path}: unexpected {type(exc).__name__} while reading ({exc})") from exc
