"""The project's scripts; the Python ones run as modules from the repository's root (python -m scripts.audit)."""
