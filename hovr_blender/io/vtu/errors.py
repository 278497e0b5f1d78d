"""The reader's one error type."""


class VtuError(ValueError):
    """A .vtu file this reader cannot use; the message names the file and, where known, the cell."""
