"""The PyFR reader's one error class: every module of the package raises it, and the package's
front (its __init__) names it without importing h5py."""


class PyFRError(ValueError):
    """A PyFR file this reader cannot use; the message names the file and the record."""
