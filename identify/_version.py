"""pseudostep's version: the one place it is written (pyproject.toml reads it, every command's
``--version`` prints it, ``identify.__version__``, ``signaldesign.__version__`` and
``cueing.__version__`` are it)."""
__version__ = "0.2.0"
