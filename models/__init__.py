"""The models this project ships (package data: ``*.safetensors``, ``motion/*.json``; see README.md).

Installed, this folder is ``deepslam.models``; :func:`models_dir` finds it. :mod:`deepslam.models.modelfile` reads
and writes the model files (safetensors with a JSON tree, no code).
"""

from pathlib import Path


def models_dir() -> Path:
    """The shipped models' folder: this package (``<repo>/models`` in a checkout,
    ``site-packages/deepslam/models`` installed)."""
    return Path(__file__).resolve().parent
